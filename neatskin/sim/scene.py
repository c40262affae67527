"""The `[scene]` of a protocol: what a dry run simulates (the skin model's fidelity, the signal level, the rig effects).

Each knob is one field of `Scene` with its unit in the name; the `[scene]` table's keys, units and
ranges are declared once in `neatskin.config.files.SceneTable` (and so listed in docs/config.md).
`parse_scene` reads the table through that schema and reports every problem at once (the protocol
loader collects them with the rest of the file's). A named preset (`scene.preset`) sets every
variability knob at once (this module holds the presets' values); knobs written in the table
override them. Every variability source is off at 0 and then costs nothing: it draws nothing and
changes no bit of the output.
The physical basis of each knob and where its preset value comes from: docs/skin.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from neatskin.config.files import SCENE_KNOBS, SCENE_PRESETS, SceneTable
from neatskin.config.schema import parse_valid
from neatskin.errors import Problem


@dataclass(frozen=True)
class Scene:
    """What a dry run simulates: the skin model's fidelity, the signal level, the rig effects."""

    fidelity: str  # "deformation" | "network"
    signal: str  # "features" | "waveforms"
    noise: bool
    placement_error_mm: float
    surface_error_mm: float = 0.0  # the real skin surface lies this far below the calibrated one
    preset: str = "ideal"
    depth_jitter_mm: float = 0.0  # std of the press depth, per press (printer z repeatability, skin height)
    fabrication_spread_fraction: float = 0.0  # std of log(channel height), per channel, once per skin
    displaced_fluid_fraction: float = 0.0  # share of the displaced fluid the sealed channels keep
    temperature_drift_k_per_h: float = 0.0  # fluid temperature ramp (may be negative: a cooling room)
    evaporation_fraction_per_h: float = 0.0  # water lost through the silicone, per hour
    press_interval_s: float = 0.0  # campaign time between presses for drift and relaxation; 0 = the G-code's
    hysteresis_fraction: float = 0.0  # dent kept right after the lift, as a share of the press depth
    relaxation_time_s: float = 30.0  # viscoelastic relaxation time of that dent
    double_layer_capacitance_uf: float = 0.0  # per electrode, in series (0 = no double layer)
    adc_skew_us: float = 0.0  # the current is sampled this long after the voltage (multiplexed ADC)
    mains_pickup_mv: float = 0.0  # amplitude of the mains hum on the voltage channel
    mains_frequency_hz: float = 50.0

    def variability(self) -> dict[str, float]:
        """The variability knobs (everything a preset sets), by name."""
        return {k: v for k, v in asdict(self).items() if k in PRESET_KNOBS}


PRESET_KNOBS = SCENE_KNOBS  # declared (unit, range, doc) in neatskin.config.files.SceneTable

_IDEAL = {k: 0.0 for k in PRESET_KNOBS} | {"relaxation_time_s": 30.0, "mains_frequency_hz": 50.0}
# paper-like: fitted to the paper's 2.03 mm mean error and 82 % within 2.75 mm (28-5-2 LM network,
# random 95/3/2 split) by benchmarks/fit_paper_like.py; the other knobs are assumed (docs/skin.md).
PAPER_LIKE = _IDEAL | {
    "placement_error_mm": 1.35,  # fitted (with depth_jitter_mm), residual in docs/skin.md
    "depth_jitter_mm": 0.2,  # fitted
    "press_interval_s": 7.78,  # the paper protocol's G-code time per press (2,800 presses in 6.05 h)
    "fabrication_spread_fraction": 0.08,
    "displaced_fluid_fraction": 0.5,
    "temperature_drift_k_per_h": 0.5,
    "evaporation_fraction_per_h": 0.002,
    "hysteresis_fraction": 0.05,
    "relaxation_time_s": 20.0,
    "double_layer_capacitance_uf": 10.0,
    "adc_skew_us": 4.0,
    # mains pickup stays off: a few mV of hum against volts of signal biases the RMS by ~1e-6 (m^2 / 2 V^2),
    # below the noise, and its noise-free live windows would double the per-press cost
    "mains_pickup_mv": 0.0,
}
PRESETS: dict[str, dict[str, float]] = {"ideal": _IDEAL, "paper-like": PAPER_LIKE}
if tuple(PRESETS) != SCENE_PRESETS or any(set(p) != set(PRESET_KNOBS) for p in PRESETS.values()):
    raise RuntimeError("the scene presets must match neatskin.config.files.SceneTable")  # pragma: no cover


def parse_scene(
    raw: Mapping[str, Any] | SceneTable, source: str, *, record_waveforms: bool
) -> tuple[Scene, list[Problem]]:
    """The scene a `[scene]` table (raw, or already read by the protocol's schema) describes, and every problem.

    A bad value is in the problems; the scene then holds the default in its place."""
    problems: list[Problem] = []
    if isinstance(raw, SceneTable):
        table = raw
    else:
        good, problems = parse_valid(SceneTable, raw, source, "scene")
        table = SceneTable(**good)
    preset = PRESETS[table.preset]
    knobs: dict[str, float] = {}
    for name in PRESET_KNOBS:
        value = getattr(table, name)
        knobs[name] = preset[name] if value is None else value
    if table.signal == "features" and record_waveforms:
        problems.append(
            Problem(
                "record.waveforms = true needs the waveforms to be simulated",
                source,
                "scene.signal",
                'set scene.signal = "waveforms" or record.waveforms = false',
            )
        )
    if knobs["relaxation_time_s"] == 0 and knobs["hysteresis_fraction"] > 0:
        problems.append(
            Problem(
                "a dent that relaxes in 0 s is no dent: hysteresis_fraction > 0 needs relaxation_time_s > 0",
                source,
                "scene.relaxation_time_s",
                "set relaxation_time_s > 0 (seconds), or hysteresis_fraction = 0",
            )
        )
    scene = Scene(
        table.fidelity,
        table.signal,
        table.noise,
        surface_error_mm=table.surface_error_mm,
        preset=table.preset,
        **knobs,
    )
    return scene, problems

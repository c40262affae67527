"""The `[scene]` of a protocol: what a dry run simulates (the skin model's fidelity, the signal level, the rig effects).

Each knob is one field of `Scene` with its unit in the name; `parse_scene` reads the protocol's
`[scene]` table and reports every problem at once (the protocol loader collects them with the
rest of the file's). A named preset (`scene.preset`) sets every variability knob at once;
knobs written in the table override the preset's values. Every variability source is off at 0
and then costs nothing: it draws nothing and changes no bit of the output.
The physical basis of each knob and where its preset value comes from: docs/skin.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from neatskin.config import TableReader
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


# knob -> (unit, may be negative, upper bound)
KNOBS: dict[str, tuple[str, bool, float | None]] = {
    "placement_error_mm": ("mm", False, None),
    "depth_jitter_mm": ("mm", False, None),
    "fabrication_spread_fraction": ("", False, 1.0),
    "displaced_fluid_fraction": ("", False, 1.0),
    "temperature_drift_k_per_h": ("K/h", True, None),
    "evaporation_fraction_per_h": ("1/h", False, 0.5),
    "press_interval_s": ("s", False, None),
    "hysteresis_fraction": ("", False, 0.99),
    "relaxation_time_s": ("s", False, None),
    "double_layer_capacitance_uf": ("uF", False, None),
    "adc_skew_us": ("us", False, None),
    "mains_pickup_mv": ("mV", False, None),
    "mains_frequency_hz": ("Hz", False, None),
}
PRESET_KNOBS = tuple(KNOBS)

_IDEAL = {k: 0.0 for k in KNOBS} | {"relaxation_time_s": 30.0, "mains_frequency_hz": 50.0}
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


def parse_scene(raw: dict, source: str, *, record_waveforms: bool) -> tuple[Scene, list[Problem]]:
    """The scene a `[scene]` table describes, and every problem found in it."""
    scene_t = TableReader(raw, "scene", source)
    fidelity = scene_t.choice("fidelity", ("deformation", "network"), "deformation")
    signal = scene_t.choice("signal", ("features", "waveforms"), "features")
    noise = scene_t.boolean("noise", True)
    preset = scene_t.choice("preset", tuple(PRESETS), "ideal") or "ideal"
    surface_error = scene_t.number("surface_error_mm", 0.0, unit="mm")
    knobs: dict[str, float] = {}
    for name, (unit, signed, upper) in KNOBS.items():
        value = scene_t.number(name, PRESETS[preset][name], minimum=None if signed else 0.0, maximum=upper, unit=unit)
        knobs[name] = PRESETS[preset][name] if value is None else value
    if signal == "features" and record_waveforms:
        scene_t.problems.append(
            Problem(
                "record.waveforms = true needs the waveforms to be simulated",
                source,
                "scene.signal",
                'set scene.signal = "waveforms" or record.waveforms = false',
            )
        )
    if knobs["relaxation_time_s"] == 0 and knobs["hysteresis_fraction"] > 0:
        scene_t.problems.append(
            Problem(
                "a dent that relaxes in 0 s is no dent: hysteresis_fraction > 0 needs relaxation_time_s > 0",
                source,
                "scene.relaxation_time_s",
                "set relaxation_time_s > 0 (seconds), or hysteresis_fraction = 0",
            )
        )
    scene_t.check_unknown()
    # a bad value is in problems; the scene then holds the default in its place
    scene = Scene(
        fidelity or "deformation",
        signal or "features",
        True if noise is None else noise,
        surface_error_mm=surface_error or 0.0,
        preset=preset,
        **knobs,
    )
    return scene, scene_t.problems

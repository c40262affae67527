"""The dry run's simulated skin, probe, DAQ and per-press conditions, built from a `DryScene`.

A `DryScene` is what the rig hands over of its protocol and plan (the scene, the layout, the printer's
calibration, the DAQ settings, the seed, the time between presses and the commanded points), so this
package never imports the engine. The inline dry rig (neatskin.rig.assembly) and the skin worker
(`skin_estimator`, built in the worker's process) make their skin, probe and DAQ here, the same way.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.sequence import Sweep
from neatskin.gcode.calibration import Calibration
from neatskin.layout import Layout
from neatskin.sim.daq import NoiseModel, SimulatedDAQ
from neatskin.sim.dryprobe import DryProbe, PressConditions
from neatskin.sim.pressestimator import PressEstimator
from neatskin.sim.recorder import STREAM_DEPTH, STREAM_PLACEMENT
from neatskin.sim.scene import Scene
from neatskin.skin.model import SkinModel, placement_error_mm
from neatskin.skin.variability import Relaxation, drift_resistivity_factor, fabrication_heights

DENT_BLOCK_PRESSES = 256  # presses whose residual dents are computed together (at most the solver's small batch)


@dataclass(frozen=True)
class DryScene:
    """What the dry run simulates, from a campaign's protocol and plan (neatskin.rig.assembly.dry_scene)."""

    scene: Scene
    layout: Layout
    calibration: Calibration  # the printer's: sensor to printer coordinates, the calibrated surface
    daq: DaqConfig  # the protocol's DAQ settings and electrical limits, so the dry run clips where the rig would
    seed: int
    probe_radius_mm: float
    demodulation: str
    window: int
    interval_s: float  # campaign seconds between presses (drift, relaxation)
    commanded_mm: np.ndarray | None = None  # (presses, 3) x, y, depth of each press in id order; with relaxation
    skin_profile: SkinModel | None = None  # a skin fitted by `neatskin skin fit`: its channels, its pinch


def dry_skin(dry: DryScene) -> SkinModel:
    """The dry run's simulated skin: its layout, scene and fitted profile."""
    scene = dry.scene
    heights = fabrication_heights(dry.layout.n_channels, getattr(scene, "fabrication_spread_fraction", 0.0), dry.seed)
    profile = dry.skin_profile
    if profile is not None and profile.channel_height_factor is not None:
        fitted = np.asarray(profile.channel_height_factor, float)
        heights = tuple(float(h) for h in (fitted if heights is None else fitted * np.asarray(heights, float)))
    fitted_pinch: dict[str, Any] = {} if profile is None else {"pinch": profile.pinch}
    if getattr(scene, "deformation", "parametric") == "fe-kernel" and scene.fidelity == "deformation":
        from neatskin.skin.kernel import KernelSpec, load_kernel

        # the paper skin's kernel is package data (34 ms to read); another geometry's is solved once and cached
        fitted_pinch["kernel"] = load_kernel(KernelSpec.for_layout(dry.layout, dry.probe_radius_mm))
    return SkinModel(
        dry.layout,
        fidelity=scene.fidelity,
        probe_radius_mm=dry.probe_radius_mm,
        placement_sigma_mm=scene.placement_error_mm,
        channel_height_factor=heights,
        displaced_fluid_fraction=getattr(scene, "displaced_fluid_fraction", 0.0),
        **fitted_pinch,
    )


def dry_probe(
    dry: DryScene, skin: SkinModel, segments_from: Callable[[float], list], *, force_only: bool = False
) -> DryProbe:
    """The dry probe on `skin` along the moves `segments_from(t0)` gives. `force_only`: the main process's probe
    beside a skin worker, which needs the depth alone (the FSR): no placement error, drift or dents."""
    scene = dry.scene
    placement = None
    if scene.placement_error_mm > 0 and not force_only:

        def placement(press_id: int) -> tuple[float, float]:
            rng = np.random.default_rng([dry.seed, press_id, STREAM_PLACEMENT])
            dx, dy = placement_error_mm(0.0, 0.0, scene.placement_error_mm, rng)
            return float(np.asarray(dx).reshape(-1)[0]), float(np.asarray(dy).reshape(-1)[0])

    return DryProbe(
        skin,
        dry.calibration,
        segments_from,
        placement_error=placement,
        surface_error_mm=scene.surface_error_mm,
        conditions=press_conditions(dry, skin, force_only=force_only),
        frame_error=frame_error(scene),
    )


def frame_error(scene: Scene) -> tuple[float, float, float] | None:
    """The scene's calibration error (x, y offset in mm, rotation in degrees of the skin's frame against the one
    the G-code was computed with), or None when there is none."""
    error = tuple(
        float(getattr(scene, name, 0.0)) for name in ("frame_offset_x_mm", "frame_offset_y_mm", "frame_rotation_deg")
    )
    return error if any(error) else None  # type: ignore[return-value]


def dry_daq(dry: DryScene, probe: DryProbe) -> SimulatedDAQ:
    """The simulated DAQ reading `probe` with the protocol's electrical limits and the scene's noise."""
    scene = dry.scene
    noise = interface_noise(NoiseModel() if scene.noise else NoiseModel.none(), scene)
    return SimulatedDAQ(
        dry.daq,
        probe.pair_resistance_ohm,
        probe.force_n,
        noise=noise,
        slot_resistance_ohm=probe.slot_resistance_ohm,
    )


def skin_estimator(dry: DryScene, sweep: Sweep) -> PressEstimator:
    """The skin worker's estimator (built in the worker; neatskin.sim.skinworker pickles this function by name):
    the same skin, conditions and DAQ as the inline dry rig, with a probe that is given each press's moves."""
    skin = dry_skin(dry)
    probe = dry_probe(dry, skin, _no_printer)
    labels = tuple(pair.label for pair in dry.layout.pairs)  # the runner's pair labels: the same layout's
    return PressEstimator(
        dry_daq(dry, probe), sweep, probe, seed=dry.seed, method=dry.demodulation, window=dry.window, pair_labels=labels
    )


def _no_printer(t0_s: float) -> list:
    raise RuntimeError("the skin worker has no printer: give the probe each press's moves (DryProbe.load_segments)")


def interface_noise(noise: NoiseModel, scene: Scene) -> NoiseModel:
    """The DAQ's noise model with the scene's electrode and ADC effects (each left as is when off)."""
    changes: dict[str, Any] = {}
    if getattr(scene, "double_layer_capacitance_uf", 0.0):
        changes["series_capacitance_f"] = scene.double_layer_capacitance_uf * 1e-6 / 2  # two electrodes in series
    if getattr(scene, "adc_skew_us", 0.0):
        changes["adc_skew_s"] = scene.adc_skew_us * 1e-6
    if getattr(scene, "mains_pickup_mv", 0.0):
        changes["mains_v"] = scene.mains_pickup_mv * 1e-3
        changes["mains_frequency_hz"] = scene.mains_frequency_hz
    return dataclasses.replace(noise, **changes) if changes else noise


def press_conditions(
    dry: DryScene, skin: SkinModel, *, force_only: bool = False
) -> Callable[[int], PressConditions] | None:
    """The per-press variability of the scene as a pure function of press_id, or None when every source is off.
    `force_only`: the depth jitter alone (what the FSR needs), for the main process beside a skin worker.

    Placement error, depth jitter (each its own random stream keyed by (seed, press_id)), drift of
    the fluid's resistivity and the residual dents of earlier presses (both from the press's
    campaign time, press_id x dry.interval_s, and the commanded presses before it), so a resumed
    campaign gets exactly what an uninterrupted one would have. The dents, and the baseline R_eq they
    leave, are computed for blocks of presses fixed by press id (`_DentBlocks`); the probe looks them up."""
    scene = dry.scene
    jitter = getattr(scene, "depth_jitter_mm", 0.0)
    drifting = bool(
        getattr(scene, "temperature_drift_k_per_h", 0.0) or getattr(scene, "evaporation_fraction_per_h", 0.0)
    )
    relaxing = bool(getattr(scene, "hysteresis_fraction", 0.0))
    if force_only:  # drift and dents change resistances only: the skin worker's probe has them
        drifting = relaxing = False
    if not (jitter or drifting or relaxing):
        return None
    interval_s, commanded = dry.interval_s, dry.commanded_mm
    relaxation = Relaxation(scene.hysteresis_fraction, scene.relaxation_time_s, interval_s) if relaxing else None

    def drift(press_id: int) -> float | None:
        if not drifting:
            return None
        return float(
            drift_resistivity_factor(
                press_id * interval_s,
                scene.temperature_drift_k_per_h,
                scene.evaporation_fraction_per_h,
                skin.resistivity_tempco_per_k,
            )
        )

    dents = None if relaxation is None or commanded is None else _DentBlocks(relaxation, commanded, skin, drift)

    def conditions(press_id: int) -> PressConditions:
        depth_offset = 0.0
        if jitter:
            depth_offset = float(np.random.default_rng([dry.seed, press_id, STREAM_DEPTH]).normal(0.0, jitter))
        factor = drift(press_id)
        extra = baseline = None
        if dents is not None:
            extra, baseline = dents.press(press_id)
        return PressConditions(
            depth_offset_mm=depth_offset,
            resistivity_factor=factor,
            extra_factor=extra,
            baseline_pair_resistance_ohm=baseline,
        )

    return conditions


class _DentBlocks:
    """The residual dents' extra R / R0 of every channel, and the pair resistances they leave before each press,
    computed for a block of DENT_BLOCK_PRESSES presses at a time (one quadrature for the block's distinct dents,
    one batched solve for its baselines) and looked up per press.

    A block is fixed by the press ids it holds, never by where a run started, so a resumed campaign gets what an
    uninterrupted one would have, bit for bit. Each baseline includes its press's drift of the resistivity."""

    def __init__(
        self, relaxation: Relaxation, commanded_mm: np.ndarray, skin: SkinModel, drift: Callable[[int], float | None]
    ) -> None:
        self.relaxation, self.commanded_mm, self.skin, self.drift = relaxation, commanded_mm, skin, drift
        self._blocks: dict[int, tuple[list[np.ndarray | None], np.ndarray]] = {}

    def press(self, press_id: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        block, k = divmod(press_id, DENT_BLOCK_PRESSES)
        if block not in self._blocks:
            if len(self._blocks) >= 2:  # presses run in id order: the block before the last is done
                del self._blocks[min(self._blocks)]
            self._blocks[block] = self._compute(block)
        extras, baselines = self._blocks[block]
        extra = extras[k]
        return (None, None) if extra is None else (extra, baselines[k])

    def _compute(self, block: int) -> tuple[list[np.ndarray | None], np.ndarray]:
        first = block * DENT_BLOCK_PRESSES
        ids = range(first, min(first + DENT_BLOCK_PRESSES, len(self.commanded_mm)))  # the program's presses only
        per_press = [self.relaxation.residual_dents(press_id, self.commanded_mm) for press_id in ids]
        counts = [len(d) for d in per_press]
        extras: list[np.ndarray | None] = [None] * len(per_press)
        baselines = np.empty((0, len(self.skin.layout.pairs)))
        if not any(counts):
            return extras, baselines
        # the presses of one position leave the same dents at the same ages: each distinct dent once
        unique, inverse = np.unique(np.concatenate([d for d in per_press if len(d)]), axis=0, return_inverse=True)
        factor = self.skin.pinch_factor(unique[:, 0], unique[:, 1], unique[:, 2])
        rows = np.split(inverse.reshape(-1), np.cumsum([c for c in counts if c])[:-1])
        dented = [k for k, c in enumerate(counts) if c]
        summed = [(factor[row] - 1.0).sum(axis=0) for row in rows]  # in dent order, as one press alone sums them
        for k, extra in zip(dented, summed):
            extras[k] = extra
        zero = np.zeros(len(dented))
        drifts = [self.drift(first + k) for k in dented]
        solved = self.skin.pair_resistance_ohm(
            zero,
            zero,
            zero,
            extra_factor=np.stack(summed),
            resistivity_factor=None if drifts[0] is None else np.array(drifts),
        )
        baselines = np.empty((len(per_press), solved.shape[1]))
        baselines[dented] = solved
        return extras, baselines

"""Rigs a campaign runs against: the dry run's simulated printer (on a pseudo-terminal) and skin, or the real rig.

Each builder imports only what its rig needs: a dry run never imports nidaqmx, a real run never
builds a simulator. Both return a `Rig` whose driver, recorder and clock the runner uses the
same way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from neatskin.acquisition.daq.base import Daq, DaqConfig
from neatskin.errors import ConfigError, HardwareError
from neatskin.rig.plan import Plan

DAQ_KINDS = ("simulated", "ni")
# lines a campaign's driver may have in flight, real rig and dry run alike: more than one only when the firmware
# names its lines (`ok N.. P.. B..`, Marlin's ADVANCED_OK); a stock Marlin without it gets one line at a time
CAMPAIGN_MAX_IN_FLIGHT = 4
SKIN_WORKER_ENV = "NEATSKIN_SKIN_WORKER"  # on | off: force the dry run's skin worker either way (benchmarks)
DENT_BLOCK_PRESSES = 256  # presses whose residual dents are computed together (at most the solver's small batch)


@dataclass
class Rig:
    kind: str  # "dry-run" | "real"
    driver: object  # neatskin.marlin.driver.MarlinDriver
    recorder: object  # SimulatedRecorder | ThreadedRecorder
    fsr_model: object
    description: dict
    closers: list[Callable[[], None]] = field(default_factory=list)
    skin: object | None = None  # the simulated skin (dry run only)
    daq: object | None = None
    skin_worker: object | None = None  # neatskin.sim.skinworker.SkinWorker when a dry run defers its estimates

    def close(self) -> None:
        for close in reversed(self.closers):
            try:
                close()
            except Exception:  # closing must not mask the error that got us here
                pass


def open_daq(kind: str, config: DaqConfig = DaqConfig(), **kwargs) -> Daq:
    """A configured backend by name. kwargs go to SimulatedDAQ (pair_resistance_ohm, force_n, noise, fsr, ...);
    the NI backend (HardwareError if nidaqmx or the device is missing) takes none."""
    if kind == "simulated":
        from neatskin.sim.daq import SimulatedDAQ

        if "pair_resistance_ohm" not in kwargs:
            raise ConfigError(
                "the simulated DAQ needs pair_resistance_ohm(times_s) -> (times, pairs)",
                field="pair_resistance_ohm",
                fix="pass the skin model's pair resistance callable",
            )
        return SimulatedDAQ(config, **kwargs)
    if kind == "ni":
        if kwargs:
            raise ConfigError(
                f"the NI backend takes no {', '.join(sorted(kwargs))}", field="daq", fix="pass only a DaqConfig"
            )
        from neatskin.acquisition.daq.nidaqmx_backend import NiDAQ

        return NiDAQ(config)
    raise ConfigError(f"unknown DAQ kind {kind!r}", field="daq", fix=f"use one of {', '.join(DAQ_KINDS)}")


def daq_config(protocol):
    """The DAQ settings of a protocol, its electrical limits included (ADC range, voltage gain, compliance),
    so a dry run clips where the protocol's rig would."""
    return DaqConfig(
        rate_hz=protocol.acquisition.rate_hz,
        amplitude_a=protocol.excitation.amplitude_a,
        frequency_hz=protocol.excitation.frequency_hz,
        voltage_range_v=protocol.acquisition.adc_range_v,
        voltage_gain=protocol.acquisition.voltage_gain,
        compliance_v=protocol.excitation.compliance_v,
    )


def use_skin_worker(protocol, planned: int | None, skin_worker: bool | None = None) -> bool:
    """Whether a dry run computes its pair estimates in a worker process (neatskin.sim.skinworker).

    `skin_worker` True or False forces it (tests, benchmarks), as does SKIN_WORKER_ENV=on|off; by default a
    features scene of at least the batching writer's BATCH_FROM_PRESSES planned presses on a machine with a
    second core does, and everything else (the smoke protocol, short tests, the waveforms scene) stays inline."""
    import os

    from neatskin.datasets.writer import BATCH_FROM_PRESSES

    if protocol.scene.signal != "features":
        return False
    if skin_worker is None:
        forced = os.environ.get(SKIN_WORKER_ENV, "").strip().lower()
        if forced in ("on", "off"):
            return forced == "on"
        if forced:
            raise ConfigError(
                f"{SKIN_WORKER_ENV}={forced!r} is not a skin worker setting",
                field=SKIN_WORKER_ENV,
                fix="set it to on or off, or unset it for the default",
            )
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        return planned is not None and planned >= BATCH_FROM_PRESSES and cores >= 2
    return bool(skin_worker)


def build_dry_rig(
    protocol,
    plan: Plan,
    *,
    connect_timeout_s: float = 0.2,
    wire_log=None,
    printer_faults=None,
    skin_worker: bool | None = None,
) -> Rig:
    """The simulated printer on a real pty (reached through pyserial), the simulated skin and DAQ.

    With a skin worker (`use_skin_worker(protocol, plan.n_presses, skin_worker)`) the pair estimates are computed
    in its own process, started first so its start-up overlaps the printer's connect; the main process keeps
    the FSR (the probe's depth alone) and the rest of the skin for the physical limit."""
    from neatskin.marlin.driver import DriverConfig, MarlinDriver
    from neatskin.sim.printer import SimulatedPrinter
    from neatskin.sim.recorder import SimulatedRecorder

    scene, sweep = protocol.scene, plan.sweep
    timing = press_timing(protocol, plan)
    closers: list[Callable[[], None]] = []
    worker = None
    if use_skin_worker(protocol, plan.n_presses, skin_worker):
        import functools

        from neatskin.sim.skinworker import SkinWorker

        worker = SkinWorker(functools.partial(skin_estimator, protocol, sweep, timing)).start()
        closers.append(worker.close)
    skin = dry_skin(protocol)
    kwargs = {} if printer_faults is None else {"faults": printer_faults}
    # a Marlin built with ADVANCED_OK (`ok N.. P.. B..`), so the driver pipelines as it would on such a printer
    printer = SimulatedPrinter(protocol.printer, seed=protocol.seed, time_mode="virtual", advanced_ok=True, **kwargs)
    try:
        pty_path = printer.start_pty()
        closers.append(printer.stop)
        # the printer's clock is virtual: its moves take no wall time, so deadlines need no motion allowance
        driver = MarlinDriver.open(
            pty_path,
            protocol.printer.baud_rate,
            wire_log=wire_log,
            config=DriverConfig(motion_time_scale=0.0, max_in_flight=CAMPAIGN_MAX_IN_FLIGHT),
        )
        closers.append(driver.close)
        driver.connect(boot_timeout_s=connect_timeout_s)
    except BaseException:
        for close in reversed(closers):
            close()
        raise

    probe = dry_probe(protocol, skin, printer.segments, timing, force_only=worker is not None)
    daq = dry_daq(protocol, probe)
    recorder = SimulatedRecorder(
        daq,
        sweep,
        probe,
        printer.now_s,
        seed=protocol.seed,
        signal=scene.signal,
        method=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
        fsr_enabled=protocol.fsr_enabled,
        keep_waveforms=protocol.record_waveforms,
        worker=worker,
    )
    profile = getattr(protocol, "skin_profile", None)
    description = {
        "kind": "dry-run",
        "printer": "simulated Marlin on " + pty_path,
        "daq": "simulated",
        "skin": {
            "fidelity": scene.fidelity,
            "signal": scene.signal,
            "noise": scene.noise,
            "placement_error_mm": scene.placement_error_mm,
            "surface_error_mm": scene.surface_error_mm,
            "probe_radius_mm": protocol.press.press.probe_diameter_mm / 2,
            "preset": getattr(scene, "preset", "ideal"),
            "skin_profile": None if profile is None else str(protocol.skin_profile_path),
            **(scene.variability() if hasattr(scene, "variability") else {}),
        },
    }
    return Rig("dry-run", driver, recorder, daq.fsr, description, closers, skin=skin, daq=daq, skin_worker=worker)


def dry_skin(protocol):
    """The dry run's simulated skin (SkinModel) of a protocol: its layout, scene and fitted profile."""
    from neatskin.skin.model import SkinModel
    from neatskin.skin.variability import fabrication_heights

    scene = protocol.scene
    heights = fabrication_heights(
        protocol.layout.n_channels, getattr(scene, "fabrication_spread_fraction", 0.0), protocol.seed
    )
    profile = getattr(protocol, "skin_profile", None)  # a skin fitted by `neatskin skin fit`: its channels, its pinch
    if profile is not None and profile.channel_height_factor is not None:
        fitted = np.asarray(profile.channel_height_factor, float)
        heights = tuple(float(h) for h in (fitted if heights is None else fitted * np.asarray(heights, float)))
    return SkinModel(
        protocol.layout,
        fidelity=scene.fidelity,
        probe_radius_mm=protocol.press.press.probe_diameter_mm / 2,
        placement_sigma_mm=scene.placement_error_mm,
        channel_height_factor=heights,
        displaced_fluid_fraction=getattr(scene, "displaced_fluid_fraction", 0.0),
        **({} if profile is None else {"pinch": profile.pinch}),
    )


def press_timing(protocol, plan: Plan) -> PressTiming:
    """What the scene's drift and dents need of the plan: the campaign time between presses (the scene's
    press_interval_s, else the G-code's own time per press) and, with relaxation, every press's commanded point."""
    scene = protocol.scene
    interval_s = getattr(scene, "press_interval_s", 0.0) or plan.press_interval_s
    relaxing = bool(getattr(scene, "hysteresis_fraction", 0.0))
    return PressTiming(interval_s, plan.commanded_mm(protocol.press.press.depth_mm) if relaxing else None)


@dataclass(frozen=True)
class PressTiming:
    interval_s: float  # campaign seconds between presses
    commanded_mm: np.ndarray | None  # (presses, 3) x, y, depth of each press in id order; None without relaxation


def dry_probe(protocol, skin, segments_from: Callable[[float], list], timing: PressTiming, *, force_only: bool = False):
    """The dry probe on `skin` along the moves `segments_from(t0)` gives. `force_only`: the main process's probe
    beside a skin worker, which needs the depth alone (the FSR): no placement error, drift or dents."""
    from neatskin.sim.recorder import STREAM_PLACEMENT, DryProbe
    from neatskin.skin.model import placement_error_mm

    scene = protocol.scene
    placement = None
    if scene.placement_error_mm > 0 and not force_only:

        def placement(press_id: int) -> tuple[float, float]:
            rng = np.random.default_rng([protocol.seed, press_id, STREAM_PLACEMENT])
            dx, dy = placement_error_mm(0.0, 0.0, scene.placement_error_mm, rng)
            return float(np.asarray(dx).reshape(-1)[0]), float(np.asarray(dy).reshape(-1)[0])

    return DryProbe(
        skin,
        protocol.printer.calibration,
        segments_from,
        placement_error=placement,
        surface_error_mm=scene.surface_error_mm,
        conditions=press_conditions(protocol, skin, timing, force_only=force_only),
    )


def dry_daq(protocol, probe):
    """The simulated DAQ reading `probe` with the protocol's electrical limits and the scene's noise."""
    from neatskin.sim.daq import NoiseModel, SimulatedDAQ

    scene = protocol.scene
    noise = interface_noise(NoiseModel() if scene.noise else NoiseModel.none(), scene)
    return SimulatedDAQ(
        daq_config(protocol),
        probe.pair_resistance_ohm,
        probe.force_n,
        noise=noise,
        slot_resistance_ohm=probe.slot_resistance_ohm,
    )


def skin_estimator(protocol, sweep, timing: PressTiming):
    """The skin worker's estimator (built in the worker; neatskin.sim.skinworker pickles this function by name):
    the same skin, conditions and DAQ as the inline dry rig, with a probe that is given each press's moves."""
    from neatskin.sim.skinworker import PressEstimator

    skin = dry_skin(protocol)
    probe = dry_probe(protocol, skin, _no_printer, timing)
    return PressEstimator(
        dry_daq(protocol, probe),
        sweep,
        probe,
        seed=protocol.seed,
        method=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
    )


def _no_printer(t0_s: float) -> list:
    raise RuntimeError("the skin worker has no printer: give the probe each press's moves (DryProbe.load_segments)")


def interface_noise(noise, scene):
    """The DAQ's noise model with the scene's electrode and ADC effects (each left as is when off)."""
    import dataclasses

    changes = {}
    if getattr(scene, "double_layer_capacitance_uf", 0.0):
        changes["series_capacitance_f"] = scene.double_layer_capacitance_uf * 1e-6 / 2  # two electrodes in series
    if getattr(scene, "adc_skew_us", 0.0):
        changes["adc_skew_s"] = scene.adc_skew_us * 1e-6
    if getattr(scene, "mains_pickup_mv", 0.0):
        changes["mains_v"] = scene.mains_pickup_mv * 1e-3
        changes["mains_frequency_hz"] = scene.mains_frequency_hz
    return dataclasses.replace(noise, **changes) if changes else noise


def press_conditions(protocol, skin, timing: PressTiming, *, force_only: bool = False):
    """The per-press variability of the scene as a pure function of press_id, or None when every source is off.
    `force_only`: the depth jitter alone (what the FSR needs), for the main process beside a skin worker.

    Placement error, depth jitter (each its own random stream keyed by (seed, press_id)), drift of
    the fluid's resistivity and the residual dents of earlier presses (both from the press's
    campaign time, press_id x press_interval_s, and the commanded presses before it), so a resumed
    campaign gets exactly what an uninterrupted one would have. The dents, and the baseline R_eq they
    leave, are computed for blocks of presses fixed by press id (`_DentBlocks`); the probe looks them up."""
    from neatskin.sim.recorder import STREAM_DEPTH, PressConditions
    from neatskin.skin.variability import Relaxation, drift_resistivity_factor

    scene = protocol.scene
    jitter = getattr(scene, "depth_jitter_mm", 0.0)
    drifting = bool(
        getattr(scene, "temperature_drift_k_per_h", 0.0) or getattr(scene, "evaporation_fraction_per_h", 0.0)
    )
    relaxing = bool(getattr(scene, "hysteresis_fraction", 0.0))
    if force_only:  # drift and dents change resistances only: the skin worker's probe has them
        drifting = relaxing = False
    if not (jitter or drifting or relaxing):
        return None
    interval_s, commanded = timing.interval_s, timing.commanded_mm
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
            depth_offset = float(np.random.default_rng([protocol.seed, press_id, STREAM_DEPTH]).normal(0.0, jitter))
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

    def __init__(self, relaxation, commanded_mm: np.ndarray, skin, drift: Callable[[int], float | None]) -> None:
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


def build_real_rig(
    protocol,
    plan: Plan,
    *,
    port: str,
    daq_kind: str = "ni",
    baud_rate: int | None = None,
    connect_timeout_s: float = 5.0,
    wire_log=None,
) -> Rig:
    """The printer on a serial port and the DAQ; errors are HardwareErrors raised before any motion."""
    from neatskin.acquisition.fsr import FsrModel
    from neatskin.marlin.driver import DriverConfig, MarlinDriver
    from neatskin.rig.recorder import ThreadedRecorder

    closers: list[Callable[[], None]] = []
    try:  # the printer first: a port that does not answer is the commonest set-up mistake
        driver = MarlinDriver.open(
            port,
            baud_rate or protocol.printer.baud_rate,
            wire_log=wire_log,
            config=DriverConfig(max_in_flight=CAMPAIGN_MAX_IN_FLIGHT),
        )
        closers.append(driver.close)
        driver.connect(boot_timeout_s=connect_timeout_s)
        daq = open_daq(daq_kind, daq_config(protocol))
        closers.append(daq.close)
    except HardwareError:
        for close in reversed(closers):
            close()
        raise
    except Exception as exc:
        for close in reversed(closers):
            close()
        raise HardwareError(f"cannot open the rig (printer on {port}, DAQ {daq_kind}): {exc}") from exc
    recorder = ThreadedRecorder(
        daq,
        plan.sweep,
        method=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
        fsr_enabled=protocol.fsr_enabled,
        keep_waveforms=protocol.record_waveforms,
    )
    description = {"kind": "real", "printer": port, "daq": daq_kind}
    return Rig("real", driver, recorder, FsrModel(), description, closers, daq=daq)

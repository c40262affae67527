"""The dry run's rig: the simulated printer on a real pseudo-terminal (reached through pyserial), the simulated
skin and DAQ, and the skin worker that computes the estimates in a second process.

The dry scene itself (skin, probe, DAQ, per-press conditions) is built by neatskin.sim.dryscene from the
`DryScene` that `dry_scene` makes of the protocol and the plan: the simulator never imports the engine.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import Any

from neatskin.datasets import writer as dataset_writer  # its batch rule looked up when used (tests set it)
from neatskin.datasets.paths import PHYSICAL_LIMIT
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.rig.assembly import CAMPAIGN_MAX_IN_FLIGHT, Rig, daq_config
from neatskin.rig.physlimit import physical_limit_table, write_physical_limit
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.sim.daq import SimulatedDAQ
from neatskin.sim.dryscene import DryProbe, DryScene, dry_daq, dry_probe, dry_skin, skin_estimator
from neatskin.sim.faults import FaultConfig
from neatskin.sim.printer import SimulatedPrinter
from neatskin.sim.recorder import SimulatedRecorder
from neatskin.sim.skinworker import SKIN_WORKER_ENV as SKIN_WORKER_ENV  # tests set it through this module
from neatskin.sim.skinworker import SkinWorker, discard_prestarted, forced_by_env, usable_cores
from neatskin.skin.model import SkinModel


def use_skin_worker(protocol: CampaignProtocol, planned: int | None, skin_worker: bool | None = None) -> bool:
    """Whether a dry run computes its pair estimates in a worker process (neatskin.sim.skinworker).

    `skin_worker` True or False forces it (tests, benchmarks), as does SKIN_WORKER_ENV=on|off; by default a
    features scene of at least the batching writer's BATCH_FROM_PRESSES planned presses on a machine with a
    second core does, and everything else (the smoke protocol, short tests, the waveforms scene) stays inline."""
    if protocol.scene.signal != "features":
        return False
    if skin_worker is None:
        forced = forced_by_env()
        if forced is not None:
            return forced
        return planned is not None and planned >= dataset_writer.BATCH_FROM_PRESSES and usable_cores() >= 2
    return bool(skin_worker)


def build_dry_rig(
    protocol: CampaignProtocol,
    plan: Plan,
    *,
    connect_timeout_s: float = 0.2,
    wire_log: str | PathLike[str] | None = None,
    printer_faults: FaultConfig | None = None,
    skin_worker: bool | None = None,
) -> Rig:
    """The simulated printer on a real pty (reached through pyserial), the simulated skin and DAQ.

    With a skin worker (`use_skin_worker(protocol, plan.n_presses, skin_worker)`) the pair estimates are computed
    in its own process, started first so its start-up overlaps the printer's connect; the main process keeps
    the FSR (the probe's depth alone) and the rest of the skin for the physical limit."""
    scene, sweep = protocol.scene, plan.sweep
    dry = dry_scene(protocol, plan)
    closers: list[Callable[[], None]] = []
    worker = None
    if use_skin_worker(protocol, plan.n_presses, skin_worker):
        worker = SkinWorker(functools.partial(skin_estimator, dry, sweep)).start()  # adopts a prestarted one
        closers.append(worker.close)
    else:
        discard_prestarted()  # the CLI launched one for a campaign that turns out to compute inline
    skin = dry_skin(dry)
    faults = FaultConfig() if printer_faults is None else printer_faults
    # a Marlin built with ADVANCED_OK (`ok N.. P.. B..`), so the driver pipelines as it would on such a printer
    printer = SimulatedPrinter(
        protocol.printer, seed=protocol.seed, faults=faults, time_mode="virtual", advanced_ok=True
    )
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

    probe = dry_probe(dry, skin, printer.segments, force_only=worker is not None)
    daq = dry_daq(dry, probe)
    recorder = simulated_recorder(protocol, plan, dry, daq, probe, printer.now_s, worker=worker)
    closers.append(recorder.close)  # its FSR noise thread ends with the rig
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
    # the physical limit depends on no press: with a skin worker the main process waits for the worker's estimates
    # part of the time, so a thread computes it then, and the campaign's end only writes it (the same table)
    table = Ahead(functools.partial(physical_limit_table, protocol, plan, skin, daq)).result if worker else None
    derived = {PHYSICAL_LIMIT: functools.partial(_physical_limit, protocol, plan, skin, daq, table)}
    batch = dataset_writer.dry_run_batch_presses(plan.n_presses)
    return Rig("dry-run", driver, recorder, daq.fsr, description, closers, derived, fsync=False, batch_presses=batch)


def _physical_limit(
    protocol: CampaignProtocol,
    plan: Plan,
    skin: SkinModel,
    daq: SimulatedDAQ,
    table: Callable[[], Any] | None,
    folder: Path,
) -> Path:
    return write_physical_limit(folder, protocol, plan, skin, daq, table=table)


class Ahead:
    """A pure computation started now in a daemon thread; `result()` waits for it and gives its value, or raises
    its error. Nothing waits for a result nobody asks for (an interrupted campaign writes no physical limit)."""

    def __init__(self, compute: Callable[[], Any], name: str = "physical-limit") -> None:
        self._compute = compute
        self._value: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._value = self._compute()
        except BaseException as exc:  # raised again, in the caller's thread, by result()
            self._error = exc

    def result(self) -> Any:
        self._thread.join()  # a finite computation (no I/O): it ends
        if self._error is not None:
            raise self._error
        return self._value


def dry_scene(protocol: CampaignProtocol, plan: Plan) -> DryScene:
    """What the dry run simulates of a campaign (neatskin.sim.dryscene): the protocol's scene, layout,
    calibration, DAQ settings and seed; from the plan, the campaign time between presses (the scene's
    press_interval_s, else the G-code's own time per press) and, with relaxation, every press's commanded point."""
    scene = protocol.scene
    relaxing = bool(getattr(scene, "hysteresis_fraction", 0.0))
    return DryScene(
        scene=scene,
        layout=protocol.layout,
        calibration=protocol.printer.calibration,
        daq=daq_config(protocol),
        seed=protocol.seed,
        probe_radius_mm=protocol.press.press.probe_diameter_mm / 2,
        demodulation=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
        interval_s=getattr(scene, "press_interval_s", 0.0) or plan.press_interval_s,
        commanded_mm=plan.commanded_mm(protocol.press.press.depth_mm) if relaxing else None,
        skin_profile=getattr(protocol, "skin_profile", None),
    )


def simulated_recorder(
    protocol: CampaignProtocol,
    plan: Plan,
    dry: DryScene,
    daq: SimulatedDAQ,
    probe: DryProbe,
    now_s: Callable[[], float],
    worker: SkinWorker | None = None,
) -> SimulatedRecorder:
    """The simulated DAQ's recorder on the protocol's acquisition settings, timed by `now_s` (the simulated
    printer's clock in a dry run, the line tracker's on a real printer)."""
    return SimulatedRecorder(
        daq,
        plan.sweep,
        probe,
        now_s,
        seed=protocol.seed,
        signal=dry.scene.signal,
        method=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
        fsr_enabled=protocol.fsr_enabled,
        keep_waveforms=protocol.record_waveforms,
        worker=worker,
    )

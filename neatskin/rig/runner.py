"""The campaign runner: executes a protocol's plan press by press against a rig, writing each press durably.

The plan (G-code press blocks, the mux sweep, the sweeps per press) is built and checked from
the protocol before anything moves; the rig (dry run or real) only executes it. Each finished
press is durable on disk before the next starts; Ctrl-C stops after the press in flight, lifts
the probe and leaves a campaign that `resume` finishes with no press lost or duplicated.
"""

from __future__ import annotations

import math
import shutil
import signal
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from neatskin.errors import ConfigError, DataError, Problem
from neatskin.rig.protocol import Protocol, file_sha256, load_protocol

INPUTS_DIR = "inputs"
WIRE_LOG = "wire.log"
MAX_PRESS_ATTEMPTS = 3  # a press the FSR never saw is retried twice, then stored flagged


@dataclass(frozen=True)
class Plan:
    program: object  # neatskin.gcode.program.PressProgram
    sweep: object  # neatskin.acquisition.sequence.Sweep
    n_sweeps: int  # sweeps recorded per press, from parking above the target to lifted
    hold_s: float
    printer_time_s: float  # the G-code's estimate for the whole campaign

    @property
    def n_presses(self) -> int:
        return len(self.program.presses)


@dataclass(frozen=True)
class CampaignResult:
    folder: Path
    planned: int
    completed: int
    written_now: int
    flagged: int
    interrupted: bool
    wall_s: float
    printer_time_s: float


def build_plan(protocol: Protocol) -> Plan:
    """Everything the runner will do, checked before any motion (bounds, hold long enough to sample)."""
    from neatskin.acquisition.sequence import SweepTiming, build_sweep
    from neatskin.gcode.motion import phase_durations_s
    from neatskin.gcode.spec import build_from_spec

    program, _, _ = build_from_spec(
        protocol.press, hold_in_gcode=False, layout=protocol.layout, profile=protocol.printer
    )
    acq = protocol.acquisition
    sweep = build_sweep(
        protocol.wiring,
        SweepTiming(rate_hz=acq.rate_hz, settle_samples=acq.settle_samples, live_samples=acq.live_samples),
    )
    hold_s = protocol.press.press.hold_s
    min_hold = 2 * sweep.duration_s
    if hold_s < min_hold:
        raise ConfigError(
            f"hold_s = {hold_s} s holds the probe for less than two sweeps of the {sweep.n_pairs} "
            f"pairs ({min_hold:.3f} s), so no whole sweep would be recorded at depth",
            file=str(protocol.path),
            field="press.hold_s",
            fix=f"set hold_s >= {math.ceil(min_hold * 10) / 10}",
        )
    durations = phase_durations_s(program, protocol.printer)  # (presses, [travel, descend, press, lift])
    per_press = durations[:, 1:].sum(axis=1) + hold_s
    n_sweeps = int(math.ceil((per_press.max() + 0.5) / sweep.duration_s))
    total = float(durations.sum() + hold_s * len(program.presses))
    return Plan(program, sweep, n_sweeps, hold_s, total)


def _copy_inputs(protocol: Protocol, folder: Path) -> dict[str, dict]:
    """Copy the protocol and the files it names into the campaign folder, so resume needs nothing else."""
    inputs = folder / INPUTS_DIR
    inputs.mkdir(parents=True, exist_ok=True)
    refs = {}
    for key, src in protocol.referenced_files.items():
        dst = inputs / f"{key}.toml"
        if not dst.exists():
            shutil.copyfile(src, dst)
        refs[key] = {"path": f"{INPUTS_DIR}/{key}.toml", "source": str(src), "sha256": file_sha256(dst)}
    return refs


def _check_folder(folder: Path, resume: bool) -> None:
    if resume:
        return
    if folder.exists() and any(folder.iterdir()):
        raise ConfigError(
            f"the output folder {folder} already holds files",
            field="--out",
            fix=f"choose a new folder, or continue it with: neatskin campaign resume {folder}",
        )


def run_campaign(
    protocol: Protocol,
    folder: str | Path,
    *,
    dry_run: bool = True,
    port: str | None = None,
    daq_kind: str = "ni",
    resume: bool = False,
    progress: bool = True,
    limit: int | None = None,
    report: bool = True,
    printer_faults=None,
    connect_timeout_s: float | None = None,
) -> CampaignResult:
    """Run (or resume) a campaign into `folder`; returns what was done."""
    from neatskin.datasets.manifest import create_manifest, update_manifest, utc_now_iso
    from neatskin.datasets.writer import CampaignWriter

    folder = Path(folder)
    wall0 = time.perf_counter()
    _check_folder(folder, resume)
    plan = build_plan(protocol)  # every check that needs no hardware happens here, before any motion
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    try:
        rig = _open_rig(
            protocol,
            plan,
            dry_run=dry_run,
            port=port,
            daq_kind=daq_kind,
            printer_faults=printer_faults,
            connect_timeout_s=connect_timeout_s,
            wire_log=folder / WIRE_LOG,
        )
    except BaseException:
        if created:  # a rig that cannot be opened leaves nothing behind
            shutil.rmtree(folder, ignore_errors=True)
        raise
    try:
        refs = _copy_inputs(protocol, folder)
        pair_labels = [p.label for p in protocol.layout.pairs]
        metadata = {
            "campaign": protocol.name,
            "protocol": refs["protocol"],
            "layout": refs["layout"],
            "wiring": refs["wiring"],
            "printer": refs["printer"],
            "seed": protocol.seed,
            "rig": rig.kind,
        }
        if resume and (folder / "manifest.json").exists():
            update_manifest(folder, status="running", resumed_at=utc_now_iso(), rig=rig.description)
        else:
            create_manifest(
                folder,
                campaign=protocol.name,
                protocol_as_run=protocol.raw,
                seed=protocol.seed,
                **refs,
                pairs=[[p.i, p.j] for p in protocol.layout.pairs],
                rig=rig.description,
                labels=(
                    "fsr"
                    if protocol.fsr_enabled
                    else "motion sync only (no FSR in this protocol): presses are not force-checked"
                ),
                sweep={
                    "rate_hz": plan.sweep.rate_hz,
                    "samples": plan.sweep.n_samples,
                    "settle_samples": protocol.acquisition.settle_samples,
                    "live_samples": protocol.acquisition.live_samples,
                    "sweeps_per_press": plan.n_sweeps,
                    "hold_s": plan.hold_s,
                    "demodulation": protocol.acquisition.demodulation,
                    "window": protocol.acquisition.window,
                },
                counts={"planned": plan.n_presses, "completed": 0},
                printer_time_estimate_s=plan.printer_time_s,
            )
        writer = CampaignWriter(folder, protocol.layout.pairs, metadata)
        done = writer.completed_press_ids()
        todo = [b for b in plan.program.presses if b.press_id not in done]
        if limit is not None:
            todo = todo[:limit]
        written, flagged, interrupted = _press_loop(protocol, plan, rig, writer, todo, pair_labels, len(done), progress)
        completed = len(writer.completed_press_ids())
        status = "complete" if completed == plan.n_presses else "interrupted"
        if status == "complete":
            _finish_program(rig, plan)
            writer.finalize()
        writer.close()
        update_manifest(
            folder, status=status, finished_at=utc_now_iso(), counts={"completed": completed, "flagged": flagged}
        )
        if status == "complete" and rig.skin is not None:
            write_physical_limit(folder, protocol, plan, rig)
    finally:
        rig.close()
    result = CampaignResult(
        folder,
        plan.n_presses,
        completed,
        written,
        flagged,
        interrupted,
        time.perf_counter() - wall0,
        plan.printer_time_s,
    )
    if report and status == "complete":
        from neatskin.baselines.report import run_baselines

        try:
            run_baselines(folder, split="both", progress=progress)
        except KeyboardInterrupt:
            raise KeyboardInterrupt(
                f"the campaign's data is complete in {folder}; only its baseline report was "
                f"stopped: make it with neatskin baselines {folder}"
            ) from None
    return result


def _open_rig(protocol, plan, *, dry_run, port, daq_kind, printer_faults, connect_timeout_s, wire_log):
    from neatskin.rig.assembly import build_dry_rig, build_real_rig

    timeout = {} if connect_timeout_s is None else {"connect_timeout_s": connect_timeout_s}
    if dry_run:
        return build_dry_rig(protocol, plan.sweep, printer_faults=printer_faults, wire_log=wire_log, **timeout)
    if not port:
        raise ConfigError(
            "a real run needs the printer's serial port",
            field="--port",
            fix="pass --port /dev/ttyUSB0 (or --dry-run for the simulated rig)",
        )
    return build_real_rig(protocol, plan.sweep, port=port, daq_kind=daq_kind, wire_log=wire_log, **timeout)


class _StopRequest:
    """Ctrl-C sets a flag; the press in flight finishes, the probe lifts, the campaign stays resumable."""

    def __init__(self) -> None:
        self.requested = False
        self._previous = None

    def __enter__(self):
        def handler(signum, frame):
            if self.requested:  # a second Ctrl-C: stop now
                raise KeyboardInterrupt
            self.requested = True

        try:
            self._previous = signal.signal(signal.SIGINT, handler)
        except ValueError:  # not the main thread: no handler, Ctrl-C behaves as usual
            self._previous = None
        return self

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def _press_loop(protocol, plan, rig, writer, todo, pair_labels, already_done, progress):
    from tqdm import tqdm

    driver = rig.driver
    driver.send_lines(plan.program.preamble, source="preamble")
    flagged = written = 0
    bar = tqdm(
        total=plan.n_presses,
        initial=already_done,
        unit="press",
        disable=not progress,
        desc=f"{protocol.name} ({rig.kind})",
        dynamic_ncols=True,
    )
    interrupted = False
    with _StopRequest() as stop:
        checkpoint = _checkpoint(protocol, plan, driver, writer.folder, stop)
        for block in todo:
            row, waveforms = _run_press(protocol, plan, rig, block, pair_labels)
            writer.write_press(row, waveforms)
            written += 1
            flagged += bool(row["flags"])
            bar.update(1)
            bar.set_postfix(flagged=flagged)
            if stop.requested:
                interrupted = True
                driver.send_lines(plan.program.postamble[:2] if plan.program.postamble else (), source="lift")
                break
            if block is not todo[-1] and not checkpoint.after_press(block.press_id, row["flags"]):
                interrupted = True
                break
        checkpoint.finished("stopped" if interrupted else "finished")
    bar.close()
    return written, flagged, interrupted


def _checkpoint(protocol, plan, driver, folder, stop):
    """The safe point between presses (neatskin.rig.control): pause lifts and waits, stop lifts and parks."""
    from neatskin.rig.control import DEFAULT_FSR_MISS_LIMIT, Checkpoint

    post = plan.program.postamble  # lift to the safe height, park, lift, M400, done marker
    return Checkpoint(
        folder,
        lift=lambda: driver.send_lines((*post[:1], "M400"), source="pause lift"),
        park=lambda: driver.send_lines((*post[:3], "M400"), source="stop park"),
        fsr_miss_limit=getattr(protocol, "fsr_pause_after_misses", DEFAULT_FSR_MISS_LIMIT),
        interrupted=lambda: stop.requested,
    )


def _hold_lines(hold_s: float) -> tuple[str, ...]:
    return (f"G4 P{int(round(hold_s * 1000))}", "M400")


def _run_press(protocol, plan, rig, block, pair_labels):
    from neatskin.rig.pressrow import fsr_label, press_values

    driver, recorder = rig.driver, rig.recorder
    extra_flags: list[str] = []
    for attempt in range(MAX_PRESS_ATTEMPTS):
        started = datetime.now(UTC)
        for phase in block.phases:
            driver.send_lines(phase.lines, source=f"press {block.press_id} {phase.name}")
            if phase.name == "travel":
                recorder.begin(block.press_id, plan.n_sweeps)
            elif phase.name == "descend":
                recorder.mark("contact")
            elif phase.name == "press":
                recorder.mark("hold_start")
                driver.send_lines(_hold_lines(plan.hold_s), source=f"press {block.press_id} hold")
                recorder.mark("hold_end")
            elif phase.name == "lift":
                recorder.mark("lifted")
        record = recorder.end()
        label = fsr_label(
            record.fsr_v, record.fsr_rate_hz, rig.fsr_model, record.first_sample, record.marks, record.rate_hz
        )
        if not label.missed or attempt == MAX_PRESS_ATTEMPTS - 1:
            break
        extra_flags.append(f"fsr_retry:{attempt + 1}")
    values = press_values(record.estimates, record.marks, pair_labels)
    row = {
        "campaign": protocol.name,
        "press_id": block.press_id,
        "position_id": block.position_id,
        "repeat": block.repeat,
        "x_mm": block.x_mm,
        "y_mm": block.y_mm,
        "depth_mm": protocol.press.press.depth_mm,
        "started_at": started,
        "finished_at": datetime.now(UTC),
        "fsr_onset_s": label.onset_s,
        "fsr_offset_s": label.offset_s,
        "fsr_peak_n": label.peak_n,
        "flags": [*extra_flags, *label.flags, *values.flags],
        "R_ohm": values.resistance_ohm,
        "dR_ohm": values.delta_r_ohm,
    }
    return row, record.waveforms


def _finish_program(rig, plan) -> None:
    rig.driver.send_lines(plan.program.postamble, source="postamble")


def write_physical_limit(folder: Path, protocol: Protocol, plan: Plan, rig) -> Path:
    """Per position, the Cramér-Rao bound on the position error that the simulated skin and noise allow."""
    import pandas as pd
    import pyarrow as pa

    from neatskin.baselines.crb import cramer_rao_bound_mm
    from neatskin.datasets.writer import write_table_durably

    blocks = {b.position_id: b for b in plan.program.presses}
    ids = np.array(sorted(blocks))
    x = np.array([blocks[i].x_mm for i in ids])
    y = np.array([blocks[i].y_mm for i in ids])
    depth = np.full(ids.shape, protocol.press.press.depth_mm)
    jac = rig.skin.jacobian_mm(x, y, depth)  # (positions, pairs, 2) ohm / mm
    std = _dr_noise_std_ohm(protocol, plan, rig, x, y, depth)
    crb = np.array([cramer_rao_bound_mm(jac[k : k + 1], noise_std=std[k])[0] for k in range(len(ids))])
    table = pa.Table.from_pandas(
        pd.DataFrame({"position_id": ids.astype(np.int32), "x_mm": x, "y_mm": y, "crb_mm": crb}), preserve_index=False
    )
    return write_table_durably(folder / "physical_limit.parquet", table)


def _dr_noise_std_ohm(protocol, plan, rig, x, y, depth) -> np.ndarray:
    """Std of one press's dR per pair (positions, pairs): the estimator noise of the baseline and pressed sweeps
    that a press averages, drawn from the simulated DAQ's features path at the unpressed and pressed states."""
    from neatskin.sim.daq import SimulatedDAQ

    sweep, draws = plan.sweep, 64
    pressed = rig.skin.pair_resistance_ohm(x, y, depth)
    states = np.vstack([np.asarray(rig.skin.baseline_pair_resistance_ohm)[None], pressed])  # (1 + positions, pairs)
    var = np.empty_like(states)
    for k, state in enumerate(states):
        daq = SimulatedDAQ(rig.daq.config, lambda t, s=state: np.broadcast_to(s, (len(t), s.size)), noise=rig.daq.noise)
        est = daq.estimate_sweep(
            sweep,
            np.random.default_rng([protocol.seed, 10**6, k]),
            0.0,
            method=protocol.acquisition.demodulation,
            window=protocol.acquisition.window,
            n_sweeps=draws,
        )
        var[k] = est.resistance_ohm.var(axis=0)
    durations = _typical_phases_s(plan, protocol)
    n_base = max(1, int(durations[1] // sweep.duration_s))  # sweeps while descending through air
    n_press = max(1, int(plan.hold_s // sweep.duration_s) - 1)  # whole sweeps inside the hold
    return np.sqrt(var[0] / n_base + var[1:] / n_press)


def _typical_phases_s(plan, protocol) -> np.ndarray:
    from neatskin.gcode.motion import phase_durations_s

    return np.median(phase_durations_s(plan.program, protocol.printer), axis=0)


def _check_inputs_unchanged(folder: Path, manifest: dict) -> None:
    """The copies in inputs/ must be the files the campaign started with: a changed seed, layout or
    calibration would mix two campaigns in one dataset."""
    problems = []
    for key in ("protocol", "layout", "wiring", "printer"):
        ref = manifest.get(key)
        if not isinstance(ref, dict) or "sha256" not in ref:
            continue
        path = folder / ref["path"]
        actual = file_sha256(path) if path.is_file() else "missing"
        if actual != ref["sha256"]:
            problems.append(
                Problem(
                    f"{ref['path']} is not the file this campaign started with (sha256 {actual[:12]}, "
                    f"recorded {ref['sha256'][:12]})",
                    str(path),
                    key,
                    "restore the original file; to run changed settings, start a new campaign with a new --out folder",
                )
            )
    if problems:
        raise DataError(problems=problems)


def resume_campaign(folder: str | Path, **kwargs) -> CampaignResult:
    """Finish a campaign from its folder: the protocol and files it ran with are the copies in inputs/."""
    from neatskin.datasets.manifest import read_manifest

    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest.get("status") == "complete":
        report = "" if (folder / "report.md").exists() else f"; for its baseline report: neatskin baselines {folder}"
        raise DataError(
            f"campaign {folder} is already complete: every press is on disk",
            file=str(folder / "manifest.json"),
            field="status",
            fix=f"nothing to resume{report}",
        )
    _check_inputs_unchanged(folder, manifest)
    protocol = load_protocol(
        folder / INPUTS_DIR / "protocol.toml",
        file_overrides={k: folder / INPUTS_DIR / f"{k}.toml" for k in ("layout", "wiring", "printer")},
    )
    rig_kind = (manifest.get("rig") or {}).get("kind", "dry-run")
    kwargs.setdefault("dry_run", rig_kind == "dry-run")
    return run_campaign(protocol, folder, resume=True, **kwargs)

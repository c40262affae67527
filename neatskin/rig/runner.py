"""The campaign runner: executes a protocol's plan press by press against a rig, writing each press durably.

The plan (G-code press blocks, the mux sweep, the sweeps per press) is built and checked from
the protocol before anything moves; the rig (dry run or real) only executes it. On the real rig each
finished press is durable on disk (fsync'd) before the next starts; a dry run writes its presses in
batches (neatskin.datasets.writer.dry_run_batch_presses), each flushed before the loop ends, pauses or
stops, since a kill's lost batch is recomputed identically from (seed, press_id). Ctrl-C stops after the
press in flight, lifts the probe and leaves a campaign that `resume` finishes with no press lost or
duplicated. The press loop itself is neatskin.rig.pressing; this module builds the plan, the folder and
the rig around it, and finishes the campaign.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neatskin.datasets.lock import CampaignLock
from neatskin.datasets.manifest import read_manifest, update_manifest, utc_now_iso
from neatskin.datasets.paths import CONSOLIDATED_NAME, press_parts
from neatskin.datasets.writer import CampaignWriter, file_sha256, read_parquet
from neatskin.errors import ConfigError, DataError
from neatskin.rig.assembly import DerivedFiles, Rig, build_real_rig
from neatskin.rig.campaignreport import make_report, report_or_note
from neatskin.rig.folder import (
    INPUT_KEYS,
    check_folder,
    check_inputs_unchanged,
    check_parts_writable,
    copy_inputs,
    create_campaign_folder,
    load_inputs,
    missing_derived_files,
    refuse_merge,
    restore_consolidated,
    rig_kind,
)
from neatskin.rig.plan import Plan, build_plan
from neatskin.rig.pressing import finish_program, press_loop
from neatskin.rig.protocol import CampaignProtocol

if TYPE_CHECKING:  # the dry run's printer faults: a real run never imports the simulator
    from neatskin.sim.faults import FaultConfig

WIRE_LOG = "wire.log"
log = logging.getLogger(__name__)


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
    report_summary: str | None = None  # the baseline report's table, for the CLI to show
    dry_run: bool = True  # the simulated rig (its printer time runs faster than the wall), or the real one


def run_campaign(
    protocol: CampaignProtocol,
    folder: str | Path,
    *,
    dry_run: bool = True,
    port: str | None = None,
    daq_kind: str = "ni",
    resume: bool = False,
    progress: bool = True,
    limit: int | None = None,
    report: bool = True,
    printer_faults: FaultConfig | None = None,
    connect_timeout_s: float | None = None,
    plan: Plan | None = None,
) -> CampaignResult:
    """Run (or resume) a campaign into `folder`; returns what was done. The folder is locked while it runs:
    a second run or resume into it gets a DataError naming this process. `plan`: build_plan(protocol), when the
    caller has built it already (the CLI's dry run, for its rails warning); else it is built here."""
    folder = Path(folder)
    wall0 = time.perf_counter()
    check_folder(folder, resume)
    if plan is None:
        plan = build_plan(protocol)  # every check that needs no hardware happens here, before any motion
    kind = "dry-run" if dry_run else "real"
    if resume:
        lock = CampaignLock(folder).acquire()
    else:
        lock = create_campaign_folder(protocol, plan, folder, kind)
    try:
        result, status = _run_locked(
            protocol,
            plan,
            folder,
            wall0,
            created=not resume,
            dry_run=dry_run,
            port=port,
            daq_kind=daq_kind,
            progress=progress,
            limit=limit,
            printer_faults=printer_faults,
            connect_timeout_s=connect_timeout_s,
        )
        if report and status == "complete":
            result = dataclasses.replace(result, report_summary=make_report(folder, progress, result.completed))
    finally:
        lock.release()
    return result


def _run_locked(
    protocol: CampaignProtocol,
    plan: Plan,
    folder: Path,
    wall0: float,
    *,
    created: bool,
    dry_run: bool,
    port: str | None,
    daq_kind: str,
    progress: bool,
    limit: int | None,
    printer_faults: FaultConfig | None,
    connect_timeout_s: float | None,
) -> tuple[CampaignResult, str]:
    try:
        check_parts_writable(
            folder, protocol, resuming=not created
        )  # before the rig: a folder that takes no part moves nothing
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
        if created:  # a folder that takes no part, or a rig that cannot be opened, leaves nothing behind
            shutil.rmtree(folder, ignore_errors=True)
        raise
    started = False  # a press loop with its writer: from then on the folder is a campaign's, resumable
    discard = False
    try:
        refs = copy_inputs(protocol, folder)
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
        if rig.kind == "real" and rig.description.get("daq") == "simulated":  # a real printer, a simulated skin
            metadata["daq"] = "simulated"
        resumed: dict[str, Any] = {} if created else {"resumed_at": utc_now_iso()}
        manifest = update_manifest(folder, status="running", rig=rig.description, **resumed)
        known_raw = manifest.get("parts_sha256")
        known: dict = known_raw if isinstance(known_raw, dict) else {}
        # how durable each press must be is the rig's to say (Rig.fsync, Rig.batch_presses)
        writer = CampaignWriter(
            folder,
            protocol.layout.pairs,
            metadata,
            fsync=rig.fsync,
            known_sha256=known,
            batch_presses=rig.batch_presses,
        )
        started = True
        try:
            done = writer.completed_press_ids()
            todo = plan.program.presses.excluding(done)  # a view: each block's G-code is made when pressed
            if limit is not None:
                todo = todo[:limit]
            written, flagged, interrupted = press_loop(
                protocol, plan, rig, writer, todo, pair_labels, len(done), progress
            )
            completed = len(writer.completed_press_ids())
            status = "complete" if completed == plan.n_presses else "interrupted"
            if status == "complete":
                finish_program(rig, plan)
                _finish_data(folder, plan, rig.derived_files, writer)
            else:
                update_manifest(
                    folder,
                    status=status,
                    finished_at=utc_now_iso(),
                    counts={"completed": completed, "flagged": flagged},
                    parts_sha256=_parts_sha256(read_manifest(folder), writer),
                )
        except BaseException as exc:
            _mark_stopped(folder, exc, writer)
            raise
        finally:
            writer.close()
    except BaseException as exc:
        # stopped (Ctrl-C) or failed before the press loop had a writer: left as it was the folder read "running"
        # with no process (crashed). A new one holds no press: it goes, as when the rig cannot be opened; a resumed
        # one keeps its presses and says it was stopped
        discard = created and not started
        if not created and not started:
            _mark_stopped(folder, exc)
        raise
    finally:
        rig.close()
        if discard:
            shutil.rmtree(folder, ignore_errors=True)
    result = CampaignResult(
        folder,
        plan.n_presses,
        completed,
        written,
        flagged,
        interrupted,
        time.perf_counter() - wall0,
        plan.printer_time_s,
        dry_run=dry_run,
    )
    return result, status


def _parts_sha256(manifest: dict[str, Any], writer: CampaignWriter) -> dict[str, str]:
    recorded_raw = manifest.get("parts_sha256")

    recorded: dict = recorded_raw if isinstance(recorded_raw, dict) else {}
    merged = {str(k): v for k, v in recorded.items()}
    merged.update({str(k): v for k, v in writer.part_sha256.items()})
    present = {str(i) for i in press_parts(writer.folder)}
    return {k: merged[k] for k in sorted(merged, key=int) if k in present}


def _mark_stopped(folder: Path, exc: BaseException, writer: CampaignWriter | None = None) -> None:
    """The manifest says `interrupted`, by what; with the press loop's writer, its last batch flushed first and the
    presses and parts it holds recorded (before the loop had one, a resumed campaign's counts stay as they were)."""
    if writer is not None:
        try:  # the presses in the batch are complete: keep them if the disk lets us
            writer.flush()
        except Exception as again:  # e.g. the disk is full: the batch is lost, resume presses it again
            log.warning("the last batch of presses was not written (resume presses it again): %s", again)
    try:
        parts: dict[str, Any] = (
            {}
            if writer is None
            else {
                "counts": {"completed": len(writer.completed_press_ids())},
                "parts_sha256": _parts_sha256(read_manifest(folder), writer),
            }
        )
        update_manifest(
            folder,
            status="interrupted",
            finished_at=utc_now_iso(),
            stopped_by=str(exc).splitlines()[0] if str(exc) else type(exc).__name__,
            **parts,
        )
    except Exception as again:  # the disk may still be full; the lock then tells info that nobody runs it
        log.warning("cannot mark %s interrupted: %s", folder, again)


def _finish_data(folder: Path, plan: Plan, derived: DerivedFiles, writer: CampaignWriter) -> None:
    """Consolidate, write the derived files, and only then say `complete` (with the files' sha256)."""
    consolidated = writer.finalize()
    files = {CONSOLIDATED_NAME: file_sha256(consolidated)}
    for name, write in derived.items():  # what the rig derives of its campaign (a dry run: the physical limit)
        files[name] = file_sha256(write(folder))
    flagged = _count_flagged(consolidated)
    update_manifest(
        folder,
        status="complete",
        finished_at=utc_now_iso(),
        counts={"completed": plan.n_presses, "flagged": flagged},
        files_sha256=files,
        parts_sha256=None,
    )


def _count_flagged(path: Path) -> int:
    import pyarrow.compute as pc

    flags = read_parquet(path, columns=["flags"]).column("flags")
    return int(pc.sum(pc.greater(pc.list_value_length(flags), 0)).as_py() or 0)


def _open_rig(
    protocol: CampaignProtocol,
    plan: Plan,
    *,
    dry_run: bool,
    port: str | None,
    daq_kind: str,
    printer_faults: FaultConfig | None,
    connect_timeout_s: float | None,
    wire_log: Path | None,
) -> Rig:
    # each builder has its own default connect timeout (a pty answers at once, a real printer boots)
    timeout: dict[str, Any] = {} if connect_timeout_s is None else {"connect_timeout_s": connect_timeout_s}
    if dry_run:
        from neatskin.rig.dryrig import build_dry_rig  # here: a real run never imports the simulator

        return build_dry_rig(protocol, plan, printer_faults=printer_faults, wire_log=wire_log, **timeout)
    if not port:
        raise ConfigError(
            "a real run needs the printer's serial port",
            field="--port",
            fix="pass --port /dev/ttyUSB0 (or --dry-run for the simulated rig)",
        )
    if daq_kind == "simulated":  # a real printer before the DAQ is wired: the simulated skin follows its motion
        from neatskin.rig.hilrig import build_hil_rig

        return build_hil_rig(protocol, plan, port=port, wire_log=wire_log, **timeout)
    return build_real_rig(protocol, plan, port=port, daq_kind=daq_kind, wire_log=wire_log, **timeout)


def resume_campaign(
    folder: str | Path, *, before_motion: Callable[[CampaignProtocol, Plan], None] | None = None, **kwargs: Any
) -> CampaignResult:
    """Finish a campaign from its folder: the protocol and files it ran with are the copies in inputs/.
    A complete campaign whose derived files (physical limit, report) are missing gets them regenerated.
    `before_motion(protocol, plan)` is called with the recorded protocol and its plan (the one the campaign then
    presses) once the folder's checks passed, when presses are left, before the rig opens (the CLI's pressed-rails
    warning)."""
    folder = Path(folder)
    check_folder(folder, resume=True)
    refuse_merge(folder, read_manifest(folder))  # a clear error for a folder that is no campaign, before a lock file
    with CampaignLock(folder):
        manifest = read_manifest(folder)
        kind = rig_kind(folder, manifest)
        check_inputs_unchanged(folder, manifest)
        if manifest.get("status") == "complete":
            missing = missing_derived_files(folder, manifest, report=kwargs.get("report", True))
            if missing:
                return finish_campaign(folder, report=kwargs.get("report", True), progress=kwargs.get("progress", True))
            raise DataError(
                f"campaign {folder} is already complete: every press and derived file is on disk",
                file=str(folder / "manifest.json"),
                field="status",
                fix="nothing to resume; check its files with: neatskin dataset validate " + str(folder),
            )
        kwargs.setdefault("dry_run", kind == "dry-run")
        restore_consolidated(folder, manifest)  # a damaged presses.parquet of a finalize cut short: from its copy
        rig = manifest.get("rig")
        if kind == "real":
            _resume_real_defaults(folder, rig if isinstance(rig, dict) else {}, kwargs)
        protocol = load_inputs(folder)
        plan = build_plan(protocol)
        if before_motion is not None:
            before_motion(protocol, plan)
        return run_campaign(protocol, folder, resume=True, plan=plan, **kwargs)


def _resume_real_defaults(folder: Path, rig: dict[str, Any], kwargs: dict[str, Any]) -> None:
    """A real campaign resumes on the printer's port and with the DAQ its manifest records (`rig.printer`,
    `rig.daq`) unless given; without a recorded port, one ConfigError naming the option resume has."""
    if kwargs.get("dry_run"):
        return
    if not kwargs.get("port"):
        recorded = rig.get("printer")
        if not isinstance(recorded, str) or not recorded.strip():
            raise ConfigError(
                "a real campaign resumes on the printer's serial port, and its manifest records none",
                file=str(folder / "manifest.json"),
                field="rig.printer",
                fix=f"pass it: neatskin campaign resume {folder} --port /dev/ttyUSB0",
            )
        kwargs["port"] = recorded
    if rig.get("daq") in ("ni", "simulated"):  # the DAQ it recorded (a real printer without a DAQ: simulated)
        kwargs.setdefault("daq_kind", rig["daq"])


def finish_campaign(folder: str | Path, *, report: bool = True, progress: bool = True) -> CampaignResult:
    """Make a campaign whose presses are all on disk complete: consolidate, restore a damaged presses.parquet
    from its copy, write the physical limit (dry run) and the report when they are missing."""

    folder = Path(folder)
    wall0 = time.perf_counter()
    check_folder(folder, resume=True)
    refuse_merge(folder, read_manifest(folder))
    with CampaignLock(folder):
        manifest = read_manifest(folder)
        kind = rig_kind(folder, manifest)
        check_inputs_unchanged(folder, manifest)
        protocol = load_inputs(folder)
        plan = build_plan(protocol)
        restore_consolidated(folder, manifest)
        missing = missing_derived_files(folder, manifest, report=False)
        if manifest.get("status") != "complete" or missing:
            refs = copy_inputs(protocol, folder)
            metadata = {**{k: refs[k] for k in INPUT_KEYS}, "campaign": protocol.name, "seed": protocol.seed}
            metadata["rig"] = kind
            known_raw = manifest.get("parts_sha256")
            known: dict = known_raw if isinstance(known_raw, dict) else {}
            with CampaignWriter(folder, protocol.layout.pairs, metadata, fsync=True, known_sha256=known) as writer:
                have = len(writer.completed_press_ids())
                if have < plan.n_presses:
                    raise DataError(
                        f"{plan.n_presses - have} of {plan.n_presses} presses are not on disk yet",
                        file=str(folder),
                        fix=f"press them first: neatskin campaign resume {folder}",
                    )
                rig = (
                    _open_rig(
                        protocol,
                        plan,
                        dry_run=True,
                        port=None,
                        daq_kind="ni",
                        printer_faults=None,
                        connect_timeout_s=None,
                        wire_log=None,
                    )
                    if kind == "dry-run"
                    else None
                )
                try:  # a real rig is not opened to finish: it derives no file
                    _finish_data(folder, plan, {} if rig is None else rig.derived_files, writer)
                finally:
                    if rig is not None:
                        rig.close()
        summary = report_or_note(folder, manifest, progress, plan.n_presses) if report else None
    return CampaignResult(
        folder,
        plan.n_presses,
        plan.n_presses,
        0,
        0,
        False,
        time.perf_counter() - wall0,
        plan.printer_time_s,
        summary,
        dry_run=kind == "dry-run",
    )

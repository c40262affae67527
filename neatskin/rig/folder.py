"""The campaign folder: its atomic creation, the input copies in inputs/ and their checks, and the derived
files a complete campaign must hold (what `resume` and `finish` verify and restore).

A folder is created in one step: lock, inputs/ and manifest.json are built under a hidden staging name
(`.NAME.staging-XXXX`) and renamed into place, so a kill leaves no folder or one that `resume` continues.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
from pathlib import Path
from typing import Any

import pyarrow as pa

from neatskin.datasets.durable import fsync_dir, then_instead_of_resume, write_bytes_durably, write_error
from neatskin.datasets.lock import CampaignLock, lock_state
from neatskin.datasets.manifest import create_manifest
from neatskin.datasets.paths import CONSOLIDATED_NAME, COPY_NAME, MANIFEST_NAME, PHYSICAL_LIMIT
from neatskin.datasets.writer import file_sha256
from neatskin.errors import ConfigError, DataError, Problem
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol, load_protocol

INPUTS_DIR = "inputs"
log = logging.getLogger(__name__)


def copy_inputs(protocol: CampaignProtocol, folder: Path) -> dict[str, Any]:
    """Copy the protocol and the files it names into the campaign folder, so resume needs nothing else."""
    inputs = folder / INPUTS_DIR
    inputs.mkdir(parents=True, exist_ok=True)
    refs: dict[str, Any] = {}
    for key, src in protocol.referenced_files.items():
        dst = inputs / f"{key}.toml"
        if not dst.exists():
            write_bytes_durably(dst, Path(src).read_bytes(), fsync=False)
        refs[key] = {"path": f"{INPUTS_DIR}/{key}.toml", "source": str(src), "sha256": file_sha256(dst)}
    return refs


def check_folder(folder: Path, resume: bool) -> None:
    if folder.exists() and not folder.is_dir():
        raise ConfigError(
            f"{folder} is a file, not a campaign folder",
            file=str(folder),
            field="folder" if resume else "--out",
            fix=(
                "give the campaign folder that `neatskin campaign run` wrote (it holds manifest.json), not a "
                "protocol or other file"
                if resume
                else "give --out a folder name that does not exist yet"
            ),
        )
    if resume:
        return
    if folder.exists() and any(folder.iterdir()):
        held, holder = lock_state(folder)
        running = f": another run holds this folder ({holder})" if held else ""
        if (folder / MANIFEST_NAME).is_file():  # a campaign: it can be continued
            what, fix = "", f"choose a new folder, or continue it with: neatskin campaign resume {folder}"
        else:  # resume would refuse it (no manifest.json): only a new or empty folder will do
            what = " and is no campaign (no manifest.json)"
            fix = "choose a new or empty folder for --out"
        raise ConfigError(f"the output folder {folder} already holds files{what}{running}", field="--out", fix=fix)


PROBE_BYTES = 4096  # one block: a full disk refuses it where an empty file would still be created


def check_parts_writable(folder: Path, protocol: CampaignProtocol, *, resuming: bool) -> None:
    """Before any motion: the folders the presses are written to (presses/, and waveforms/ with each of its
    position folders when the protocol records waveforms) take a file. Each is probed with a hidden temp file
    (`.write-probe.<random>.tmp`, which readers ignore), written, closed and removed; one that refuses is one
    DataError naming the folder, the cause and the fix. Without it a resume homed, travelled and pressed once
    before the first part failed to write, and threw that press away (HOSTILE #6)."""
    from neatskin.datasets.durable import probe_write
    from neatskin.datasets.paths import PRESSES_DIR, WAVEFORMS_DIR

    folders = [folder / PRESSES_DIR]
    if protocol.record_waveforms:
        waveforms = folder / WAVEFORMS_DIR
        folders.append(waveforms)
        if waveforms.is_dir():
            folders += sorted(p for p in waveforms.iterdir() if p.is_dir() and p.name.startswith("position_id="))
    for where in folders:
        target = where if where.is_dir() else where.parent  # a folder not made yet: the writer makes it there
        what = "waveforms" if WAVEFORMS_DIR in where.relative_to(folder).parts else "presses"
        try:
            probe_write(target, PROBE_BYTES)
        except OSError as exc:
            fix = str(write_error(exc, target).problems[0].fix)
            error = DataError(
                f"cannot write in this folder, where the {what} go: {os.strerror(exc.errno or 0)}; "
                "nothing was sent to the printer",
                file=str(target),
                fix=fix,
            )
            # a new campaign's folder is removed on this error: there is nothing to resume
            raise (error if resuming else for_a_new_campaign(error)) from exc


def _staging_name(folder: Path) -> Path:
    import secrets

    return folder.with_name(f".{folder.name}.staging-{secrets.token_hex(4)}")


def _remove_stale_staging(folder: Path) -> None:
    """Staging folders of runs killed before their rename (no live process holds their lock)."""
    if not folder.parent.is_dir():
        return
    for entry in folder.parent.glob(f".{folder.name}.staging-*"):
        if entry.is_dir() and not lock_state(entry)[0]:
            shutil.rmtree(entry, ignore_errors=True)


def for_a_new_campaign(error: DataError) -> DataError:
    """A write error met while a new campaign's folder is made: that folder is removed, so there is nothing to
    resume; the fix says to run the campaign again instead."""
    return then_instead_of_resume(error, "then run the campaign again")


def create_campaign_folder(protocol: CampaignProtocol, plan: Plan, folder: Path, rig_kind: str) -> CampaignLock:
    """Make the campaign folder in one atomic step: lock, inputs/ and manifest.json are built under a hidden
    staging name and renamed into place, so a kill leaves either no campaign folder or one that resumes."""
    try:
        return _create_campaign_folder(protocol, plan, folder, rig_kind)
    except DataError as exc:
        raise for_a_new_campaign(exc) from exc


def _create_campaign_folder(protocol: CampaignProtocol, plan: Plan, folder: Path, rig_kind: str) -> CampaignLock:
    _remove_stale_staging(folder)
    staging = _staging_name(folder)
    try:
        staging.mkdir(parents=True)
    except OSError as exc:
        raise write_error(exc, staging) from exc
    lock = CampaignLock(staging).acquire()
    try:
        refs = copy_inputs(protocol, staging)
        create_manifest(
            staging,
            campaign=protocol.name,
            protocol_as_run=protocol.raw,
            seed=protocol.seed,
            **refs,
            pairs=[[p.i, p.j] for p in protocol.layout.pairs],
            rig={"kind": rig_kind},
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
                # the mux's visiting order: slot k of every sweep measures pair pair_order[k] (layout.pairs
                # index), through chip mux_chip[k] at address mux_address[k]
                "pair_order": [int(k) for k in plan.sweep.order],
                "mux_chip": [int(plan.sweep.chip[k]) for k in plan.sweep.order],
                "mux_address": [int(plan.sweep.address[k]) for k in plan.sweep.order],
            },
            counts={"planned": plan.n_presses, "completed": 0},
            printer_time_estimate_s=plan.printer_time_s,
        )
        try:
            if folder.exists():
                folder.rmdir()  # empty (checked): the rename needs the name free
            os.rename(staging, folder)
            fsync_dir(folder.parent)
        except OSError as exc:
            if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):  # another run renamed its folder in first
                check_folder(folder, resume=False)  # names the run that holds it
            raise write_error(exc, folder) from exc
        lock.moved_to(folder)
    except BaseException:
        lock.release()
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return lock


INPUT_KEYS = ("protocol", "layout", "wiring", "printer")
OPTIONAL_INPUT_KEYS = ("skin_profile",)  # copied and checked when the protocol names one


def _recorded_input_sha(folder: Path, manifest: dict) -> dict[str, str | None]:
    """The sha256 each input file had when the campaign started: from the manifest, else from the parquet
    metadata (every press file carries the same references), so deleting a hash switches no check off."""
    from neatskin.datasets.reader import read_metadata  # pandas: a new campaign's start does not need it

    try:
        metadata = read_metadata(folder)
    except (DataError, OSError, pa.ArrowException):  # a truncated presses.parquet: the manifest's hashes hold
        metadata = {}
    out: dict[str, str | None] = {}
    optional = [key for key in OPTIONAL_INPUT_KEYS if key in manifest or (folder / INPUTS_DIR / f"{key}.toml").exists()]
    for key in (*INPUT_KEYS, *optional):
        shas = [ref.get("sha256") for ref in (manifest.get(key), metadata.get(key)) if isinstance(ref, dict)]
        shas = [sha for sha in shas if isinstance(sha, str)]
        if len(set(shas)) > 1:
            raise DataError(
                f"the manifest's sha256 of {key} differs from the one the presses were written with",
                file=str(folder / "manifest.json"),
                field=f"{key}.sha256",
                fix="restore the campaign's own manifest.json; a changed input starts a new campaign",
            )
        out[key] = shas[0] if shas else None
    return out


def check_inputs_unchanged(folder: Path, manifest: dict) -> None:
    """The copies in inputs/ must be the files the campaign started with: a changed seed, layout or
    calibration would mix two campaigns in one dataset."""
    problems = []
    for key, recorded in _recorded_input_sha(folder, manifest).items():
        path = folder / INPUTS_DIR / f"{key}.toml"
        if recorded is None:
            problems.append(
                Problem(
                    f"no sha256 of {INPUTS_DIR}/{key}.toml is recorded, so the file cannot be checked",
                    str(folder / "manifest.json"),
                    f"{key}.sha256",
                    "restore the campaign's own manifest.json (it records the sha256 of every input)",
                )
            )
            continue
        actual = file_sha256(path) if path.is_file() else "missing"
        if actual != recorded:
            problems.append(
                Problem(
                    f"{INPUTS_DIR}/{key}.toml is not the file this campaign started with (sha256 {actual[:12]}, "
                    f"recorded {recorded[:12]})",
                    str(path),
                    key,
                    "restore the original file; to run changed settings, start a new campaign with a new --out folder",
                )
            )
    if problems:
        raise DataError(problems=problems)


def refuse_merge(folder: Path, manifest: dict) -> None:
    """A folder `dataset merge` wrote (manifest kind "merge") is a dataset, not a campaign: nothing to resume or finish
    (its presses come from other folders; the resume's checks would otherwise fail on its extra source column)."""
    if manifest.get("kind") == "merge":
        raise DataError(
            "this folder is a merged dataset (`neatskin dataset merge`), not a campaign: it has no presses left to "
            "press and no derived files of a campaign",
            file=str(folder / "manifest.json"),
            field="kind",
            fix="resume or finish each campaign it merged (its manifest's sources), then merge them again",
        )


def rig_kind(folder: Path, manifest: dict) -> str:
    rig = manifest.get("rig", {"kind": "dry-run"})
    kind = rig.get("kind") if isinstance(rig, dict) else None
    if kind not in ("dry-run", "real"):
        raise DataError(
            f"rig must be a table with kind 'dry-run' or 'real', got {rig!r}",
            file=str(folder / "manifest.json"),
            field="rig",
            fix='restore the manifest, or set "rig": {"kind": "dry-run"} (or "real") in it',
        )
    return kind


def load_inputs(folder: Path) -> CampaignProtocol:
    return load_protocol(
        folder / INPUTS_DIR / "protocol.toml",
        file_overrides={
            k: folder / INPUTS_DIR / f"{k}.toml"
            for k in ("layout", "wiring", "printer", "skin_profile")
            if k != "skin_profile" or (folder / INPUTS_DIR / f"{k}.toml").is_file()
        },
    )


# how a derived file that cannot be read comes back (the fix of the error naming it)
_RESTORE = {
    CONSOLIDATED_NAME: f"move it away: `neatskin campaign finish` restores it from {COPY_NAME}",
    COPY_NAME: f"restore it from a backup ({CONSOLIDATED_NAME} differs from its recorded sha256, so it is no source)",
    PHYSICAL_LIMIT: "move it away: `neatskin campaign finish` computes it again",
}


def skipped_report(manifest: dict) -> str | None:
    """Why a campaign has no report, when it was too small for one (the manifest's `report.skipped`), else None."""
    recorded = manifest.get("report")
    skipped = recorded.get("skipped") if isinstance(recorded, dict) else None
    return skipped if isinstance(skipped, str) else None


def missing_derived_files(folder: Path, manifest: dict, *, report: bool = True) -> list[str]:
    """What a complete campaign lacks: a consolidated file that is missing or differs from its recorded
    sha256, the physical limit of a dry run, the report (when asked for, and not skipped as the campaign was too
    small for one: the manifest's `report.skipped`)."""
    files = manifest.get("files_sha256")
    recorded: dict[str, str] = files if isinstance(files, dict) else {}
    missing = []
    for name in (CONSOLIDATED_NAME, PHYSICAL_LIMIT):
        path = folder / name
        if name == PHYSICAL_LIMIT and rig_kind(folder, manifest) != "dry-run":
            continue
        if not path.is_file() or (name in recorded and file_sha256(path, _RESTORE[name]) != recorded[name]):
            missing.append(name)
    if report and skipped_report(manifest) is None and not (folder / "report.md").is_file():
        missing.append("report.md")
    return missing


def restore_consolidated(folder: Path, manifest: dict) -> None:
    """A presses.parquet that is missing or differs from its recorded sha256 is restored from the copy
    finalize kept, when that copy matches."""
    recorded = (
        (manifest.get("files_sha256") or {}).get(CONSOLIDATED_NAME)
        if isinstance(manifest.get("files_sha256"), dict)
        else None
    )
    main, copy = folder / CONSOLIDATED_NAME, folder / COPY_NAME
    if recorded is None or (main.is_file() and file_sha256(main, _RESTORE[CONSOLIDATED_NAME]) == recorded):
        return
    if copy.is_file() and file_sha256(copy, _RESTORE[COPY_NAME]) == recorded:
        log.warning("restoring %s from %s (it differed from its recorded sha256)", main, copy)
        write_bytes_durably(main, copy.read_bytes())
        return
    raise DataError(
        "presses.parquet differs from its recorded sha256 and no intact copy is left",
        file=str(main),
        fix="restore presses.parquet from a backup; its recorded sha256 is files_sha256 in manifest.json",
    )

"""Validation of a campaign folder's files against their records: presses.parquet and the committed parts against
the sha256 the manifest recorded (a file re-encoded without a change passes), parts whose rows are not what their
name says, waveform parts of presses not in the dataset or in another press's partition, and presses of a campaign
that records waveforms without theirs. `validate.py` gathers these with its other checks."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pyarrow as pa

from neatskin.datasets.paths import (
    CONSOLIDATED_NAME,
    COPY_NAME,
    PRESSES_DIR,
    part_press_id,
    press_parts,
    waveform_parts,
)
from neatskin.datasets.scan import DatasetScan
from neatskin.datasets.waveformcheck import lost_waveforms_problem, presses_without_waveforms, records_waveforms
from neatskin.datasets.writer import file_sha256, read_parquet
from neatskin.errors import DataError, Problem


def where(files: list[Path]) -> str:
    """The file a problem names: the first of several, with how many more."""
    return str(files[0]) if len(files) == 1 else f"{files[0]} (and {len(files) - 1} more files)"


def unreadable_fix(file: Path) -> str:
    """The fix for a press file that cannot be read (or differs from its record): presses.parquet has a copy."""
    if file.name == CONSOLIDATED_NAME:
        return (
            f"restore it from its copy: neatskin campaign finish {file.parent} (or cp {file.parent / COPY_NAME} "
            f"{file} when that copy's sha256 matches files_sha256 in manifest.json)"
        )
    return "move the file out of the folder; resume the campaign to press again"


def _same_rows(path: Path, copy: Path, recorded_sha256: str) -> bool:
    """Whether `path` holds the same rows as the campaign's intact copy: a file re-encoded without a change
    (e.g. a pandas round trip) is fine, a changed value or a flipped bit is not."""
    try:
        if not copy.is_file() or file_sha256(copy) != recorded_sha256:
            return False
        original = read_parquet(copy)
        return original.equals(read_parquet(path).cast(original.schema))
    except (OSError, pa.ArrowException, ValueError, DataError):
        return False


def _sha256(path: Path, problems: list[Problem], unreadable: set[Path]) -> str | None:
    """The file's sha256, or None when it cannot be read: a problem naming it (unless the scan already named it)."""
    try:
        return file_sha256(path)
    except DataError as exc:
        if path not in unreadable:
            problems.extend(exc.problems)
        return None


def integrity_problems(folder: Path, manifest: dict | None, scan: DatasetScan) -> list[Problem]:
    """Recorded sha256 (presses.parquet, committed parts) and parts whose content is not what their name says."""
    problems: list[Problem] = []
    manifest = manifest or {}
    files_raw = manifest.get("files_sha256")
    files: dict = files_raw if isinstance(files_raw, dict) else {}
    parts_sha_raw = manifest.get("parts_sha256")
    parts_sha: dict = parts_sha_raw if isinstance(parts_sha_raw, dict) else {}
    consolidated = folder / CONSOLIDATED_NAME
    unreadable = {Path(file) for file, _ in scan.unreadable}
    if (
        CONSOLIDATED_NAME in files
        and consolidated.is_file()
        and _sha256(consolidated, problems, unreadable) not in (None, files[CONSOLIDATED_NAME])
        and not _same_rows(consolidated, folder / COPY_NAME, files[CONSOLIDATED_NAME])
    ):
        problems.append(
            Problem(
                "presses.parquet differs from the file the campaign finished with (sha256 and rows): damaged or edited",
                str(consolidated),
                "files_sha256",
                unreadable_fix(consolidated),
            )
        )
    for press_id, part in press_parts(folder).items():
        if str(press_id) in parts_sha and _sha256(part, problems, unreadable) not in (None, parts_sha[str(press_id)]):
            problems.append(
                Problem(
                    "the part changed after it was committed (sha256 differs from the manifest's)",
                    str(part),
                    "parts_sha256",
                    "move the part out of presses/ and resume: the press is pressed again",
                )
            )
    ids_by_file = scan.keys.groupby("file", sort=False)["press_id"]
    for index, (file, schema) in enumerate(zip(scan.files, scan.schemas)):
        expected = part_press_id(file)
        if file.parent.name != "presses" or expected is None or "press_id" not in schema.names:
            continue
        ids = [int(i) for i in ids_by_file.get_group(index)] if index in ids_by_file.groups else []
        if not part_ids_valid(expected, ids):
            problems.append(
                Problem(
                    f"the part's name says press {expected} but it holds press id(s) {ids[:5]}",
                    str(file),
                    "press_id",
                    "move the part out of presses/ and resume: the press is pressed again",
                )
            )
    return problems


def part_ids_valid(first_press_id: int, ids: list) -> bool:
    """A part `part-{N:06d}.parquet` holds one or more rows: its press ids start with N and strictly increase
    (a part of one row holding press N is the common case)."""
    if not ids or ids[0] != first_press_id or any(i is None for i in ids):
        return False
    return all(a < b for a, b in zip(ids, ids[1:]))


def waveform_problems(
    folder: Path, rows: pd.DataFrame, manifest: dict | None = None, files: list[Path] | None = None
) -> list[Problem]:
    """Waveform parts must belong to a press of the dataset and sit in that press's position partition; in a
    campaign that records waveforms, every press must have one (`rows`: the scan's keys, whose `file` indexes
    `files`)."""
    known = rows[["press_id", "position_id"]].dropna()
    position_of = dict(zip(known["press_id"].astype(int), known["position_id"].astype(int)))
    problems: list[Problem] = []
    lost = presses_without_waveforms(folder, position_of) if records_waveforms(manifest) else []
    if lost:
        holders: dict[int, Path | None] = dict.fromkeys(lost)
        if files is not None and "file" in rows:
            in_lost = rows[rows["press_id"].isin(lost)]
            for press_id, index in zip(in_lost["press_id"].astype(int), in_lost["file"].astype(int)):
                if files[index].parent.name == PRESSES_DIR:  # a press part: moving it out presses it again
                    holders[press_id] = files[index]
        problems.append(lost_waveforms_problem(folder, lost, position_of, holders))
    orphans, misplaced = [], []
    for press_id, part in waveform_parts(folder).items():
        if press_id not in position_of:
            orphans.append(part)
        elif part.parent.name != f"position_id={position_of[press_id]}":
            misplaced.append(part)
    if orphans:
        problems.append(
            Problem(
                f"{len(orphans)} waveform part(s) of presses that are not in the dataset",
                where(orphans),
                "press_id",
                "resume the campaign (it deletes orphans and presses them again) or delete the parts",
            )
        )
    if misplaced:
        problems.append(
            Problem(
                f"{len(misplaced)} waveform part(s) in another press's position_id partition",
                where(misplaced),
                "position_id",
                "move each part to waveforms/position_id=<its press's position_id>/",
            )
        )
    return problems

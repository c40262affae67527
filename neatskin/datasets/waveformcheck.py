"""The raw waveforms a campaign owes: whether it records them and which committed presses lack their waveform part.
`validate` reports such presses; the writer refuses to resume or finish a campaign without them, so a campaign is
never marked complete with a press's raw samples silently gone."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from neatskin.datasets.manifest import read_manifest
from neatskin.datasets.paths import CONSOLIDATED_NAME, PRESSES_DIR, WAVEFORMS_DIR, part_name, waveform_parts
from neatskin.datasets.tables import read_parquet
from neatskin.errors import DataError, Problem


def records_waveforms(manifest: Mapping[str, Any] | None) -> bool:
    """Whether the campaign keeps every press's raw waveforms: the protocol as run its manifest records says
    `record.waveforms = true` (the runner writes that; a folder of hand-made waveform parts owes none)."""
    run = (manifest or {}).get("protocol_as_run")
    record = run.get("record") if isinstance(run, Mapping) else None
    return isinstance(record, Mapping) and record.get("waveforms") is True


def waveform_part_path(folder: Path, position_id: int, press_id: int) -> Path:
    """Where the writer puts a press's waveform part: waveforms/position_id=K/part-{press_id:06d}.parquet."""
    return Path(folder) / WAVEFORMS_DIR / f"position_id={position_id}" / part_name(press_id)


def presses_without_waveforms(folder: Path, press_ids: Iterable[int]) -> list[int]:
    """The committed presses (sorted) that have no waveform part in the folder."""
    have = waveform_parts(folder)
    return sorted({int(i) for i in press_ids} - have.keys())


def lost_waveforms_problem(
    folder: Path, lost: list[int], positions: Mapping[int, int], holders: Mapping[int, Path | None]
) -> Problem:
    """The one problem for committed presses whose waveform part is gone: names the presses and the first missing
    part; the fix re-presses them (their press parts moved out, then resume) or, for presses already consolidated
    into presses.parquet, restores the parts from a backup."""
    first = lost[0]
    missing = waveform_part_path(folder, positions.get(first, -1), first) if first in positions else None
    where = str(missing) if missing else str(Path(folder) / WAVEFORMS_DIR / "position_id=*" / part_name(first))
    if len(lost) > 1:
        where += f" (and {len(lost) - 1} more)"
    shown = ", ".join(str(i) for i in lost[:8]) + (f", ... ({len(lost)} in all)" if len(lost) > 8 else "")
    parts = sorted({p.name for i in lost if (p := holders.get(i)) is not None})
    if len(parts) == len({holders.get(i) for i in lost}) and parts:  # every lost press is in a press part
        fix = (
            f"move {', '.join(parts[:4])}{' ...' if len(parts) > 4 else ''} out of {Path(folder) / PRESSES_DIR} "
            "and resume: the presses it holds are pressed again, with their waveforms"
        )
    else:
        fix = (
            "restore the waveform part(s) from a backup: the presses' rows are in presses.parquet, their raw "
            "samples are gone (a dry run run again with the same seed gives them back bit for bit)"
        )
    return Problem(
        f"press(es) {shown} of a campaign that records waveforms have no waveform part", where, "waveforms", fix
    )


def refuse_lost_waveforms(
    folder: Path, completed: set[int], parts: Mapping[int, Path], part_last: Mapping[int, int]
) -> None:
    """The writer's check on resume or finish: a committed press (`completed`; `parts` by first press id, each
    holding ids up to `part_last[first]`) of a running or interrupted campaign that records waveforms, whose
    waveform part is gone, is a DataError. A real press's raw samples cannot be recomputed, and the campaign must
    not be completed without them; a complete campaign is not marked so again (validate names the loss)."""
    if not completed:
        return
    try:
        manifest = read_manifest(folder)
    except DataError:
        return  # no manifest (a writer used alone), or a damaged one: the runner refuses that itself
    if not records_waveforms(manifest) or manifest.get("status") == "complete":
        return
    lost = presses_without_waveforms(folder, completed)
    if not lost:
        return
    holders = {i: next((parts[f] for f, last in part_last.items() if f <= i <= last), None) for i in lost}
    source = holders[lost[0]] or Path(folder) / CONSOLIDATED_NAME
    keys = read_parquet(source, columns=["press_id", "position_id"]).to_pydict()
    positions = dict(zip(keys["press_id"], keys["position_id"]))
    raise DataError(problems=[lost_waveforms_problem(folder, lost, positions, holders)])

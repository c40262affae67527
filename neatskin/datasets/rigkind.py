"""Which rig recorded a dataset's presses (a simulated or a real printer, a simulated or a real DAQ), read from its
manifest or its presses' metadata: what `dataset merge` refuses to mix unless told to, what a merged manifest records
per source, and what a merged dataset's card says of each source's share. Pure: dicts in, values out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from neatskin.errors import DataError

SIMULATED, REAL = "simulated", "real"
MIXED = "mixed"  # a merged manifest's rig kind when its sources' rigs differ (merge --allow-mixed-rigs)


@dataclass(frozen=True)
class RigKind:
    """A rig as merge compares rigs: the printer and the DAQ, each simulated, real, or None (not recorded)."""

    printer: str | None
    daq: str | None

    def __post_init__(self) -> None:
        for part in (self.printer, self.daq):
            if part not in (SIMULATED, REAL, None):
                raise ValueError(f"a rig part is {SIMULATED!r}, {REAL!r} or None, not {part!r}")

    @property
    def known(self) -> bool:
        return self.printer is not None

    def describe(self) -> str:
        """In words, as the card and merge's error say it: 'dry run', 'real printer with a simulated DAQ'..."""
        if self.printer is None:
            return "rig not recorded"
        if self.printer == SIMULATED:
            return "dry run" if self.daq != REAL else "simulated printer with a real DAQ"
        if self.daq == SIMULATED:
            return "real printer with a simulated DAQ"
        return "real printer and DAQ" if self.daq == REAL else "real printer, DAQ not recorded"


def _kind_of(rig_kind: Any, daq: Any) -> RigKind:
    """From the runner's words: rig kind 'dry-run' or 'real', DAQ 'simulated' or a backend's name (ni, ...)."""
    if rig_kind == "dry-run":
        return RigKind(SIMULATED, SIMULATED if daq in (None, SIMULATED) else REAL)
    if rig_kind == REAL:
        return RigKind(REAL, None if daq is None else SIMULATED if daq == SIMULATED else REAL)
    return RigKind(None, None)


def rig_kind(manifest: dict[str, Any], metadata: dict[str, Any]) -> RigKind:
    """A campaign's rig: the manifest's `rig` ({kind, daq, ...}), else the presses' `neatskin.rig`/`neatskin.daq`
    metadata (a plain presses file); RigKind(None, None) when neither says."""
    rig = manifest.get("rig")
    if isinstance(rig, dict) and rig.get("kind") in ("dry-run", REAL):
        return _kind_of(rig.get("kind"), rig.get("daq"))
    daq = metadata.get("daq")
    if metadata.get("rig") == REAL and daq is None:  # the runner writes neatskin.daq only for a simulated DAQ
        daq = REAL
    return _kind_of(metadata.get("rig"), daq)


def source_rigs(run: str, folder: str, presses: int, manifest: dict[str, Any], metadata: dict[str, Any]) -> list[dict]:
    """One source's entries for a merged manifest's `source_rigs`: one per run behind it (a merged source's own
    entries, which its rows' `source_run` already names), each with its rig kind in words and the manifest's rig;
    `folder` is the run's own folder, `source` the folder this merge read it from."""
    inner = manifest.get("source_rigs")
    if manifest.get("kind") == "merge" and isinstance(inner, list) and inner:
        return [{**entry, "source": folder} for entry in inner if isinstance(entry, dict)]
    kind = rig_kind(manifest, metadata)
    rig = manifest.get("rig")
    if not isinstance(rig, dict):
        rig = {"kind": metadata["rig"], "daq": metadata.get("daq")} if metadata.get("rig") else None
    return [
        {
            "run": run,
            "folder": folder,
            "source": folder,  # the merge's source it came through (a merged source's folder for its runs)
            "presses": presses,
            "printer": kind.printer,
            "daq": kind.daq,
            "description": kind.describe(),
            "rig": rig,
        }
    ]


def entry_kind(entry: dict[str, Any]) -> RigKind:
    """A `source_rigs` entry's RigKind (None for a value merge did not write)."""
    return RigKind(*(entry.get(k) if entry.get(k) in (SIMULATED, REAL) else None for k in ("printer", "daq")))


def distinct_kinds(entries: list[dict[str, Any]]) -> list[RigKind]:
    """The known rig kinds of the entries, in order of first appearance (an unrecorded rig mixes with none)."""
    kinds: list[RigKind] = []
    for entry in entries:
        kind = entry_kind(entry)
        if kind.known and kind not in kinds:
            kinds.append(kind)
    return kinds


def merged_rig(entries: list[dict[str, Any]]) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """A merge's manifest `rig` and its presses' rig metadata: the sources' one rig (the first's description) when
    they share one kind; {"kind": "mixed", ...} and metadata rig 'mixed' when they do not."""
    kinds = distinct_kinds(entries)
    if not kinds:
        return None, {}
    if len(kinds) > 1:
        shares = [f"{e['presses']:,} presses {e['description']} ({e['run']})" for e in entries]
        return {"kind": MIXED, "sources": "; ".join(shares)}, {"rig": MIXED}
    first = next(e for e in entries if entry_kind(e).known)
    kind = kinds[0]
    rig = first.get("rig") if isinstance(first.get("rig"), dict) and "kind" in first["rig"] else None
    if rig is None:
        rig = {"kind": "dry-run" if kind.printer == SIMULATED else REAL}
        if kind.daq is not None:
            rig["daq"] = SIMULATED if kind.daq == SIMULATED else "real"
    metadata: dict[str, Any] = {"rig": "dry-run" if kind.printer == SIMULATED else REAL}
    if kind.printer == REAL and kind.daq == SIMULATED:
        metadata["daq"] = SIMULATED  # as the runner writes it: a real printer, a simulated skin
    return rig, metadata


def refuse_mixed_rigs(rigs: list[dict[str, Any]], allow: bool) -> None:
    """One error naming every run and its rig when the sources' rigs differ (simulated against real printer or
    DAQ), unless allow: a model trained on the merge would learn from simulated and physical presses unawares."""
    kinds = distinct_kinds(rigs)
    if allow or len(kinds) < 2:
        return
    shares = "; ".join(f"{e['run']} ({e['folder']}): {e['description']}" for e in rigs if entry_kind(e).known)
    raise DataError(
        f"the campaigns were recorded on different rigs: {shares}",
        field="rig",
        fix="merge only campaigns of one rig (dry runs with dry runs, real-printer runs with their own), or pass "
        "--allow-mixed-rigs (each source's rig is then recorded in the merged manifest and named on its card)",
    )

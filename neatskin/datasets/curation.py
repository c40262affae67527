"""What every curation (describe, split and export in curate.py, merge in merging.py) shares: a source folder's
manifest (leniently for describe and merge, strictly for split and export) and status, the presses it flagged, the empty output folder, and the output's copies of the inputs.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from neatskin.datasets.lock import lock_state
from neatskin.datasets.manifest import MANIFEST_NAME, read_manifest, resolve_manifest_path
from neatskin.errors import DataError


def manifest_or_empty(folder: Path) -> dict[str, Any]:
    """The folder's manifest, or {} when it has none (a plain dataset folder) or an unreadable one: for describe and
    merge, which name a damaged manifest in their own words (info's validation line, merge's refusal)."""
    try:
        return read_manifest(folder) if folder.is_dir() else {}
    except DataError:
        return {}


def source_manifest(path: Path) -> dict[str, Any]:
    """The manifest of a source that split or export copies out: {} for a presses file or a folder without a
    manifest.json (a plain dataset folder); a manifest.json that is there but cannot be read (no permission, a
    folder or a loop of links in its place, truncated, not JSON) is read_manifest's one DataError naming it and how to
    restore it, as validate, plot and resume give it. Called before anything is written: a campaign's provenance
    and recorded host (which an export must scrub) are in that file, and an output without them would pass for a
    plain dataset."""
    if not path.is_dir() or not os.path.lexists(path / MANIFEST_NAME):
        return {}
    return read_manifest(path)


def empty_output(out: Path) -> None:
    """Refuse an output folder that holds anything: curation never overwrites data."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DataError(
            "the output folder exists and is not empty",
            file=str(out),
            fix="choose a new folder; curation never overwrites data",
        )


def flagged_mask(table: pa.Table) -> np.ndarray:
    """Which presses carry a flag."""
    return pc.greater(pc.list_value_length(table.column("flags")), 0).to_numpy(zero_copy_only=False)


def campaign_status(folder: Path, manifest: dict[str, Any]) -> str:
    """The manifest's status, told apart by the folder lock: `running (PID ..)` only while a live process
    holds it; a `running` manifest whose process is gone is `crashed`."""
    status = str(manifest.get("status"))
    held, holder = lock_state(folder)
    if held:
        return f"running ({holder})"
    if status == "running":
        who = f" (last run by {holder})" if holder else ""
        return f"crashed{who}: no process runs it; continue with neatskin campaign resume {folder}"
    return status


def copy_inputs(out: Path, sources: list[Path], manifests: list[dict[str, Any]]) -> dict[str, Any]:
    """Give the output its own copies of the input files (the first source's as inputs/<key>.toml, every
    source's under inputs/sources/<k>/), so it does not break when a source folder is deleted."""
    refs: dict[str, Any] = {}
    for k, (folder, manifest) in enumerate(zip(sources, manifests)):
        for key in ("protocol", "layout", "wiring", "printer"):
            path = resolve_manifest_path(folder, manifest, key) if folder.is_dir() else None
            if path is None or not path.is_file():
                continue
            targets = [out / "inputs" / f"{key}.toml"] if k == 0 else []
            if len(sources) > 1:
                targets.append(out / "inputs" / "sources" / str(k) / f"{key}.toml")
            for target in targets:
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, target)
            if k == 0:
                ref = manifest[key] if isinstance(manifest.get(key), dict) else {}
                refs[key] = {**ref, "path": f"inputs/{key}.toml", "source": str(path.resolve())}
    return refs

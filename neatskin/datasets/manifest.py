"""The campaign manifest (manifest.json): what was run, on what, by which software, and how far it got.

Written atomically (temp file, fsync, rename), so a kill leaves the old manifest or the new one. Fields
the runner sets (all JSON): protocol (the protocol as run, a dict), layout, wiring, printer (each a dict
with at least `path`, relative to the campaign folder or absolute, plus `name` and `sha256` when known,
or a plain path string), seed, software_version, started_at, finished_at (ISO 8601 UTC), host, status
(running | complete | interrupted), counts ({planned, completed, flagged}), and anything else useful.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from pathlib import Path
from typing import Any

import neatskin
from neatskin.campaignread import read_manifest as read_manifest  # re-exported: the datasets read it from here
from neatskin.datasets.durable import write_bytes_durably
from neatskin.datasets.paths import MANIFEST_NAME
from neatskin.errors import DataError

STATUSES = ("running", "complete", "interrupted")
MANIFEST_VERSION = 1


def utc_now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds")


def manifest_path(folder: str | os.PathLike) -> Path:
    return Path(folder) / MANIFEST_NAME


def write_manifest(folder: str | os.PathLike, manifest: dict[str, Any], *, fsync: bool = True) -> Path:
    """Replace the folder's manifest.json atomically with `manifest`."""
    status = manifest.get("status")
    if status is not None and status not in STATUSES:
        raise DataError(
            f"unknown status {status!r}",
            file=str(manifest_path(folder)),
            field="status",
            fix=f"use one of {', '.join(STATUSES)}",
        )
    try:
        text = json.dumps(manifest, indent=2, sort_keys=True, default=str, allow_nan=False)
    except ValueError as exc:
        raise DataError(
            f"manifest holds a value JSON cannot store: {exc}",
            file=str(manifest_path(folder)),
            fix="replace NaN/inf values by null",
        ) from exc
    Path(folder).mkdir(parents=True, exist_ok=True)
    return write_bytes_durably(manifest_path(folder), (text + "\n").encode(), fsync=fsync)


def create_manifest(folder: str | os.PathLike, *, fsync: bool = True, **fields: Any) -> dict[str, Any]:
    """Write a new manifest with defaults (software version, host, start time, status running) under `fields`."""
    manifest: dict[str, Any] = {
        "manifest_version": MANIFEST_VERSION,
        "software_version": neatskin.__version__,
        "host": platform.node(),
        "python": platform.python_version(),
        "started_at": utc_now_iso(),
        "finished_at": None,
        "status": "running",
    }
    manifest.update(fields)
    write_manifest(folder, manifest, fsync=fsync)
    return manifest


def update_manifest(folder: str | os.PathLike, *, fsync: bool = True, **fields: Any) -> dict[str, Any]:
    """Read, update with `fields` (a None value is stored as null), write atomically; returns the new manifest.
    Nested dicts given as values replace the old ones whole, except `counts`, which is merged."""
    manifest = read_manifest(folder)
    if isinstance(fields.get("counts"), dict) and isinstance(manifest.get("counts"), dict):
        fields["counts"] = {**manifest["counts"], **fields["counts"]}
    manifest.update(fields)
    write_manifest(folder, manifest, fsync=fsync)
    return manifest


def manifest_file_ref(manifest: dict[str, Any], key: str) -> dict[str, Any] | None:
    """The manifest's reference to an input file (`layout`, `wiring`, `printer`) as a dict with `path`."""
    value = manifest.get(key)
    if value is None:
        return None
    if isinstance(value, str):
        return {"path": value}
    if isinstance(value, dict):
        return value
    return {"path": str(value)}


def resolve_manifest_path(folder: str | os.PathLike, manifest: dict[str, Any], key: str) -> Path | None:
    """The input file `key` names, resolved against the campaign folder first, then the working directory;
    None when the manifest names none."""
    ref = manifest_file_ref(manifest, key)
    if not ref or not ref.get("path"):
        return None
    path = Path(ref["path"])
    if path.is_absolute():
        return path
    in_folder = Path(folder) / path
    return in_folder if in_folder.exists() else path

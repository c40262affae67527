"""Durable file writes: temp file in the same folder, flush + fsync, atomic rename, fsync of the folder.

A process killed at any instant leaves either the old file, or the new one complete, plus at most a
hidden temp file (`.NAME.<random>.tmp`) that readers ignore and `remove_temp_files` cleans up.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import IO

TEMP_SUFFIX = ".tmp"


def temp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}{TEMP_SUFFIX}")


def is_temp_file(path: Path) -> bool:
    return path.name.startswith(".") and path.name.endswith(TEMP_SUFFIX)


def fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_durably(
    path: Path, write: Callable[[IO[bytes]], None], *, fsync: bool = True, dir_fd: int | None = None
) -> Path:
    """Write `path` through `write(file)` so that it is either absent/old or complete, never partial.

    With fsync=True the data and the rename are on disk when this returns. `dir_fd` (an open descriptor
    of path's folder) saves reopening the folder for every file.
    """
    path = Path(path)
    tmp = temp_path_for(path)
    try:
        with open(tmp, "wb") as handle:
            write(handle)
            handle.flush()
            if fsync:
                os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if fsync:
        if dir_fd is None:
            fsync_dir(path.parent)
        else:
            os.fsync(dir_fd)
    return path


def write_bytes_durably(path: Path, data: bytes, *, fsync: bool = True) -> Path:
    return write_durably(path, lambda handle: handle.write(data), fsync=fsync)


def remove_temp_files(folder: Path) -> list[Path]:
    """Delete the temp files a killed writer left in `folder` (not recursive); return what was removed."""
    removed = []
    if folder.is_dir():
        for entry in folder.iterdir():
            if entry.is_file() and is_temp_file(entry):
                entry.unlink(missing_ok=True)
                removed.append(entry)
    return removed

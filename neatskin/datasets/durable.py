"""Durable file writes: temp file in the same folder, flush + fsync, atomic rename, fsync of the folder; and the one
clear error for a campaign file that cannot be written or read (its texts: `neatskin.oserrors`).

A process killed at any instant leaves either the old file, or the new one complete, plus at most a
hidden temp file (`.NAME.<random>.tmp`) that readers ignore and `remove_temp_files` cleans up.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import IO

from neatskin.errors import DataError
from neatskin.oserrors import os_error

TEMP_SUFFIX = ".tmp"


def write_error(exc: BaseException, path: str | os.PathLike) -> DataError:
    """One clear DataError for a failed write of `path`, naming the file, the cause and a fix (`neatskin.oserrors`'
    table; the fix ends "then resume", which `then_instead_of_resume` replaces for a write that is not a campaign's)."""
    return os_error(exc, "write", path)


def read_error(exc: OSError, path: str | os.PathLike, restore: str = "restore the file from a backup") -> DataError:
    """One clear DataError for a file that exists but cannot be read (no read permission, a folder or a loop of
    links in its place), naming the file, the system's reason and a fix; `restore` says how to get the file back."""
    return os_error(exc, "read", path, then=f"then {restore}")


def probe_write(folder: Path, size: int = 0) -> None:
    """Write `size` bytes to a hidden temp file in `folder` (named as `temp_path_for` names them, so readers ignore
    it), close and remove it: the OSError of a folder that will not take a file, before any work that needs it."""
    probe = temp_path_for(Path(folder) / ".write-probe")
    fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        os.write(fd, b"\0" * size)
    finally:
        os.close(fd)
        probe.unlink(missing_ok=True)


def then_instead_of_resume(error: DataError, then: str) -> DataError:
    """`error` with its fixes' "then resume" (a campaign's next step) replaced by `then`: for a write that is not a
    campaign's (a dataset export, split or merge: run the command again), or a new campaign removed on the error."""
    import dataclasses

    problems = [dataclasses.replace(p, fix=p.fix.replace("then resume", then)) if p.fix else p for p in error.problems]
    return DataError(problems=problems)


NAME_MAX_BYTES = 255  # the longest file name Linux's file systems take (ext4, xfs, btrfs, tmpfs)


def temp_path_for(path: Path) -> Path:
    """`.NAME.<random>.tmp` beside `path`; NAME cut short where the whole would pass the longest file name, so a name
    the file system takes (up to 255 bytes) is written, not refused for its temp file's 14 more."""
    tail = f".{secrets.token_hex(4)}{TEMP_SUFFIX}"
    name = path.name.encode()[: NAME_MAX_BYTES - 1 - len(tail)].decode(errors="ignore")
    return path.with_name(f".{name}{tail}")


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
    except OSError as exc:  # pyarrow's IO errors are OSErrors too
        _remove_quietly(tmp)
        raise write_error(exc, path) from exc
    except BaseException:
        _remove_quietly(tmp)
        raise
    if fsync:
        try:
            if dir_fd is None:
                fsync_dir(path.parent)
            else:
                os.fsync(dir_fd)
        except OSError as exc:
            raise write_error(exc, path) from exc
    return path


def _remove_quietly(tmp: Path) -> None:
    """Remove a temp file after a failed write: the same fault (a name too long, a file where a folder should be)
    refuses the removal too, and must not hide the write's own error behind a second one."""
    try:
        tmp.unlink(missing_ok=True)
    except OSError:
        pass


def write_bytes_durably(path: Path, data: bytes, *, fsync: bool = True, dir_fd: int | None = None) -> Path:
    def write(handle: IO[bytes]) -> None:
        handle.write(data)

    return write_durably(path, write, fsync=fsync, dir_fd=dir_fd)


def remove_temp_files(folder: Path) -> list[Path]:
    """Delete the temp files a killed writer left in `folder` (not recursive); return what was removed."""
    removed = []
    if folder.is_dir():
        for entry in folder.iterdir():
            if entry.is_file() and is_temp_file(entry):
                entry.unlink(missing_ok=True)
                removed.append(entry)
    return removed

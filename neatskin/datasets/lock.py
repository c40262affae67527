"""The campaign folder lock: one process at a time writes a campaign, and anyone can tell a running
campaign from a crashed one.

CAMPAIGN/campaign.lock holds the holder's PID, host and start time (JSON) and is `fcntl.flock`ed for as
long as the holder runs. The kernel drops a flock when its process dies (SIGKILL included), so liveness
is the flock, never the PID in the file: a lock file whose flock nobody holds is stale and is taken
over. The file is kept after release (emptied), so a reader opening it never races a delete.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import platform
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from neatskin.errors import DataError

LOCK_NAME = "campaign.lock"
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or last held) a campaign lock, as written in the lock file."""

    pid: int | None
    host: str | None
    started_at: str | None

    def __str__(self) -> str:
        return f"PID {self.pid} on {self.host or 'an unknown host'} (since {self.started_at or 'an unknown time'})"


def _read_holder(fd: int) -> LockHolder:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = os.read(fd, 4096)
    try:
        data = json.loads(raw.decode("utf-8")) if raw.strip() else {}
    except (UnicodeDecodeError, ValueError):
        data = {}
    if not isinstance(data, dict):
        data = {}
    pid = data.get("pid")
    return LockHolder(pid if isinstance(pid, int) else None, data.get("host"), data.get("started_at"))


def lock_state(folder: str | os.PathLike) -> tuple[bool, LockHolder | None]:
    """(held, holder): whether a live process holds the folder's lock, and who holds or last held it
    (None when the folder has no lock file or it is empty)."""
    path = Path(folder) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False, None
    try:
        holder = _read_holder(fd)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True, holder
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False, holder if holder.pid is not None else None
    finally:
        os.close(fd)


class CampaignLock:
    """An exclusive, non-blocking lock on a campaign folder (a context manager).

    Raises DataError naming the holder's PID when another live process holds it; takes over a stale lock
    left by a killed process (logging who held it). Re-entrant within one process: a nested acquire of a
    folder this process already holds shares the first lock.
    """

    _held: dict[Path, list] = {}  # resolved folder -> [fd, depth]

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.taken_over: LockHolder | None = None
        self._key: Path | None = None

    def acquire(self) -> CampaignLock:
        key = self.folder.resolve()
        if key in self._held:
            self._held[key][1] += 1
            self._key = key
            return self
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise DataError(
                f"cannot create the campaign lock: {exc.strerror}",
                file=str(self.path),
                fix=_access_fix(exc, self.folder),
            ) from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise DataError(
                f"the campaign folder is in use by {holder}",
                file=str(self.path),
                fix=f"wait for that process to finish, or stop it (kill {holder.pid}) and resume the campaign",
            ) from None
        previous = _read_holder(fd)
        if previous.pid is not None:
            self.taken_over = previous
            log.warning("taking over a stale lock of %s: %s (that process is gone)", self.folder, previous)
        info = {"pid": os.getpid(), "host": platform.node(), "started_at": datetime.now(UTC).isoformat()}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        except OSError as exc:  # a full disk must not stop the lock from working: the flock is what counts
            log.warning("cannot write the lock holder into %s: %s", self.path, exc)
        self._held[key] = [fd, 1]
        self._key = key
        return self

    def moved_to(self, folder: str | os.PathLike) -> None:
        """The locked folder was renamed (a staging folder became the campaign): follow it."""
        if self._key is None:
            return
        entry = self._held.pop(self._key)
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._key = self.folder.resolve()
        self._held[self._key] = entry

    def release(self) -> None:
        if self._key is None or self._key not in self._held:
            return
        entry = self._held[self._key]
        entry[1] -= 1
        if entry[1] == 0:
            fd = entry[0]
            del self._held[self._key]
            try:
                os.ftruncate(fd, 0)
            except OSError:
                pass
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
        self._key = None

    def __enter__(self) -> CampaignLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _access_fix(exc: OSError, folder: Path) -> str:
    if exc.errno == errno.EACCES:
        return f"give your user write permission on {folder} (e.g. chmod u+w {folder})"
    if exc.errno == errno.EPERM:
        return f"make {folder} writable for your user (chmod u+w; an immutable folder needs chattr -i)"
    if exc.errno == errno.EROFS:
        return f"{folder} is on a read-only file system: copy the campaign to a writable disk"
    if exc.errno == errno.ENOENT:
        return f"check that {folder} exists"
    return "check the folder and its file system"

"""A timestamped log of every byte sent to and received from the printer, for post-mortems.

One line per write or read: UTC time with microseconds, elapsed seconds on the monotonic
clock, direction (`>` host to printer, `<` printer to host) and the bytes as a Python bytes
literal, so a corrupted byte or a missing newline is visible exactly as it was on the wire.

Every entry is one `write(2)` on an append-only descriptor, as it happens: a killed process
leaves every entry it made in the OS, and the post-mortem's last lines are the ones that matter.
The UTC stamp's date and time of day are formatted once per second (the log sits on the
driver's per-line path; `datetime.strftime` per entry cost more than the write itself).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from os import PathLike
from pathlib import Path


class WireLog:
    """clock: the driver's monotonic seconds (the elapsed column); wall_ns: UTC nanoseconds (the stamp)."""

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self.path = Path(path)
        self.clock = clock
        self.wall_ns = wall_ns
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._lock = threading.Lock()
        self._t0 = clock()
        self._second = -1
        self._prefix = ""
        try:
            self.write("#", b"wire log opened")
        except OSError:
            self.close()
            raise

    def write(self, direction: str, data: bytes) -> None:
        micros = self.wall_ns() // 1000
        second, fraction = divmod(micros, 1_000_000)
        elapsed = self.clock() - self._t0
        with self._lock:
            if self._fd is None:
                return
            if second != self._second:
                self._second = second
                self._prefix = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(second))
            entry = f"{self._prefix}.{fraction:06d}Z {elapsed:12.6f} {direction} {data!r}\n".encode("ascii")
            view = memoryview(entry)
            while view:
                view = view[os.write(self._fd, view) :]

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


def read_wire_log(path: str | PathLike[str]) -> list[tuple[str, bytes]]:
    """(direction, bytes) for every entry of a wire log, in order (a helper for tests and post-mortems)."""
    import ast

    entries = []
    for line in Path(path).read_text(encoding="ascii").splitlines():
        parts = line.split(maxsplit=3)
        if len(parts) == 4 and parts[2] in "<>":
            entries.append((parts[2], ast.literal_eval(parts[3])))
    return entries

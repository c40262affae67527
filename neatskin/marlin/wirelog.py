"""A timestamped log of every byte sent to and received from the printer, for post-mortems.

One line per write or read: UTC time with microseconds, elapsed seconds on the monotonic
clock, direction (`>` host to printer, `<` printer to host) and the bytes as a Python bytes
literal, so a corrupted byte or a missing newline is visible exactly as it was on the wire.
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from os import PathLike
from pathlib import Path


class WireLog:
    def __init__(self, path: str | PathLike) -> None:
        self.path = Path(path)
        self._file = open(self.path, "a", encoding="ascii", buffering=1)
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.write("#", b"wire log opened")

    def write(self, direction: str, data: bytes) -> None:
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        with self._lock:
            if not self._file.closed:
                self._file.write(f"{stamp} {time.monotonic() - self._t0:12.6f} {direction} {data!r}\n")

    def close(self) -> None:
        with self._lock:
            self._file.close()


def read_wire_log(path: str | PathLike) -> list[tuple[str, bytes]]:
    """(direction, bytes) for every entry of a wire log, in order (a helper for tests and post-mortems)."""
    import ast

    entries = []
    for line in Path(path).read_text(encoding="ascii").splitlines():
        parts = line.split(maxsplit=3)
        if len(parts) == 4 and parts[2] in "<>":
            entries.append((parts[2], ast.literal_eval(parts[3])))
    return entries

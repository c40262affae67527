"""Pseudo-terminal plumbing: a raw pty pair whose slave path a pyserial client opens like a USB port.

The serving side keeps its own slave descriptor open, so the master never reads EIO between
clients (a host that closes and reopens the port, as a reconnect does).
"""

from __future__ import annotations

import os
import select
import tty
from dataclasses import dataclass


@dataclass
class PtyPair:
    master_fd: int
    slave_fd: int
    path: str

    def close(self) -> None:
        for fd in (self.master_fd, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass


def open_pty() -> PtyPair:
    """A raw (no echo, no line editing, 8-bit) pty pair; `.path` is the `/dev/pts/N` for clients."""
    master_fd, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    tty.setraw(master_fd)
    return PtyPair(master_fd, slave_fd, os.ttyname(slave_fd))


def read_available(fd: int, timeout_s: float) -> bytes:
    """Whatever the fd has within timeout_s (b"" if nothing); raises OSError when the pty is gone."""
    ready, _, _ = select.select([fd], [], [], timeout_s)
    if not ready:
        return b""
    return os.read(fd, 65536)


def write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]

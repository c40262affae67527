"""Pseudo-terminal plumbing: a raw pty pair whose slave path a pyserial client opens like a USB port.

The serving side keeps its own slave descriptor open, so the master never reads EIO between
clients (a host that closes and reopens the port, as a reconnect does). In packet mode (TIOCPKT)
the master also learns when a host flushes its input (tcflush TCIFLUSH), which pyserial's `open()`
always does: the simulated printer's stand-in for the DTR pulse that resets a real board when a host
opens its port (sim.printer).
"""

from __future__ import annotations

import fcntl
import os
import select
import struct
import termios
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


def open_pty(packet: bool = False) -> PtyPair:
    """A raw (no echo, no line editing, 8-bit) pty pair; `.path` is the `/dev/pts/N` for clients. With `packet`,
    the master is read with `read_packet` (each read is one packet: data, or a status byte)."""
    master_fd, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    tty.setraw(master_fd)
    if packet:
        fcntl.ioctl(master_fd, termios.TIOCPKT, struct.pack("i", 1))
    return PtyPair(master_fd, slave_fd, os.ttyname(slave_fd))


def read_packet(fd: int, timeout_s: float) -> tuple[bytes, bool]:
    """From a packet-mode master: (the data, whether a host flushed its input: pyserial's open) within
    timeout_s; raises OSError when the pty is gone."""
    ready, _, _ = select.select([fd], [], [], timeout_s)
    if not ready:
        return b"", False
    packet = os.read(fd, 65537)
    if not packet:
        return b"", False
    if packet[0] == termios.TIOCPKT_DATA:
        return packet[1:], False
    return b"", bool(packet[0] & termios.TIOCPKT_FLUSHREAD)


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

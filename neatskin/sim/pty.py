"""Pseudo-terminal plumbing: a raw pty pair whose slave path a pyserial client opens like a USB port.

The serving side keeps its own slave descriptor open, so the master never reads EIO between
clients (a host that closes and reopens the port, as a reconnect does). In packet mode (TIOCPKT)
the master also learns when a host flushes its input (tcflush TCIFLUSH), which pyserial's `open()`
always does: the simulated printer's stand-in for the DTR pulse that resets a real board when a host
opens its port (sim.printer). An `OpenWatch` (Linux inotify on the slave's path) tells every open and close of
the port by a host, which the master cannot see while the serving side holds the slave: the simulated printer
boots again when a host opens the port after the last one closed it, as a board with auto-reset does.
"""

from __future__ import annotations

import ctypes
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


def read_packet(fd: int, timeout_s: float, watch: OpenWatch | None = None) -> tuple[bytes, bool, bool]:
    """From a packet-mode master: (the data, whether a host flushed its input: pyserial's open, whether the watch
    has events: read them with `watch.events()`) within timeout_s; raises OSError when the pty is gone."""
    ready, _, _ = select.select([fd] if watch is None else [fd, watch.fd], [], [], timeout_s)
    watched = watch is not None and watch.fd in ready
    if fd not in ready:
        return b"", False, watched
    packet = os.read(fd, 65537)
    if not packet:
        return b"", False, watched
    if packet[0] == termios.TIOCPKT_DATA:
        return packet[1:], False, watched
    return b"", bool(packet[0] & termios.TIOCPKT_FLUSHREAD), watched


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


_IN_OPEN, _IN_CLOSE_WRITE, _IN_CLOSE_NOWRITE = 0x20, 0x08, 0x10
_EVENT = struct.Struct("iIII")  # struct inotify_event: wd, mask, cookie, len (then len bytes of name)


class OpenWatch:
    """The opens and closes of a path by any process, in order (inotify: the kernel queues every one, so a close
    and an open at once are both seen, which the master's EIO between hosts is not when the next host is quick).
    `open_watch` gives None where inotify is missing (not Linux)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def fileno(self) -> int:
        return self.fd

    def events(self) -> list[int]:
        """+1 for each open, -1 for each close since the last call (nothing waiting: [])."""
        try:
            buf = os.read(self.fd, 4096)
        except BlockingIOError:
            return []
        out, at = [], 0
        while at + _EVENT.size <= len(buf):
            _, mask, _, name_len = _EVENT.unpack_from(buf, at)
            at += _EVENT.size + name_len
            if mask & _IN_OPEN:
                out.append(1)
            if mask & (_IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE):
                out.append(-1)
        return out

    def close(self) -> None:
        try:
            os.close(self.fd)
        except OSError:
            pass


def open_watch(path: str) -> OpenWatch | None:
    """An OpenWatch on path, or None where the system has no inotify."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
    except (OSError, AttributeError):
        return None
    if fd < 0:
        return None
    if libc.inotify_add_watch(fd, os.fsencode(path), _IN_OPEN | _IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE) < 0:
        os.close(fd)
        return None
    return OpenWatch(fd)

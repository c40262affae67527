"""The byte channel under MarlinDriver: one seam, a raw descriptor for POSIX ttys and ptys, pyserial's API otherwise.

`channel_for(port)` picks the implementation once; the driver reads and writes only through
the `Channel` protocol. The raw path skips pyserial's per-call select, ioctl and timeout
bookkeeping (benchmarks/bench_marlin.py measures both side by side); every other port object
(socket://, loop://, the simulator's in-process port) goes through pyserial's read and write.
"""

from __future__ import annotations

import os
import select
import time
from typing import Protocol


class SerialPort(Protocol):
    """The part of pyserial's Serial the driver uses; any object with these works (URL handlers, the simulator)."""

    is_open: bool

    @property
    def timeout(self) -> float | None: ...

    @timeout.setter
    def timeout(self, value: float | None) -> None: ...

    @property
    def in_waiting(self) -> int: ...

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def reset_input_buffer(self) -> None: ...


class Clock(Protocol):
    """Monotonic seconds (time.monotonic, or a fake in tests)."""

    def __call__(self) -> float: ...


class Channel(Protocol):
    def read(self, timeout_s: float) -> bytes:
        """What arrived within timeout_s (b"" if nothing); OSError (or SerialException) when the port is gone."""
        ...

    def write(self, data: bytes, timeout_s: float) -> None:
        """All of data, or TimeoutError when the port takes nothing for timeout_s."""
        ...

    def cancel(self) -> None:
        """Wake a blocked read (closing)."""
        ...


class FdChannel:
    """A POSIX tty or pty by its descriptor: one select and one read per burst."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def read(self, timeout_s: float) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if not ready:
            return b""
        data = os.read(self.fd, 4096)
        if not data:
            raise OSError("end of file: the device went away")
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        view = memoryview(data)
        end = time.monotonic() + timeout_s
        while view:
            try:
                view = view[os.write(self.fd, view) :]
            except BlockingIOError:
                left = end - time.monotonic()
                if left <= 0 or not select.select([], [self.fd], [], left)[1]:
                    raise TimeoutError(
                        f"the port took no data for {timeout_s:g} s (the printer is not reading)"
                    ) from None

    def cancel(self) -> None:
        pass  # reads time out within poll_s


class SerialChannel:
    """Any pyserial-like object, through its own read/write."""

    def __init__(self, port: SerialPort) -> None:
        self.port = port

    def read(self, timeout_s: float) -> bytes:
        port = self.port
        data = port.read(port.in_waiting or 1)
        if data and port.in_waiting:  # the rest of a burst that woke us: handle it as one chunk
            data += port.read(port.in_waiting)
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        self.port.write(data)

    def cancel(self) -> None:
        cancel = getattr(self.port, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # noqa: BLE001 - a port that cannot cancel times out within poll_s
                pass


def channel_for(port: SerialPort) -> Channel:
    """The raw descriptor for an open pyserial POSIX port, pyserial's API for anything else."""
    try:
        from serial.serialposix import Serial as PosixSerial
    except ImportError:  # Windows
        return SerialChannel(port)
    if type(port) is PosixSerial and port.is_open and port.fd is not None:
        return FdChannel(port.fd)
    return SerialChannel(port)

"""The byte channel under MarlinDriver: one seam, a raw descriptor for POSIX ttys and ptys, pyserial's API otherwise.

`channel_for(port)` picks the implementation once; the driver reads and writes only through
the `Channel` protocol. The raw path skips pyserial's per-call select, ioctl and timeout
bookkeeping (benchmarks/bench_marlin.py measures both side by side); every other port object
(socket://, loop://, the simulator's in-process port) goes through pyserial's read and write.
A read waits until data comes, its timeout passes (the protocol's next deadline: None waits
for ever) or `wake()` is called; a write gives up after its timeout on either channel. Time
comes from the injected clock (the driver's), never from the time module directly.
"""

from __future__ import annotations

import os
import select
import time
from typing import Any, Protocol


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
    def read(self, timeout_s: float | None) -> bytes:
        """What arrived within timeout_s (None: until something does, or wake()); b"" if nothing;
        OSError (or SerialException) when the port is gone."""
        ...

    def write(self, data: bytes, timeout_s: float) -> None:
        """All of data, or TimeoutError when the port takes nothing for timeout_s."""
        ...

    def wake(self) -> None:
        """End a blocked read now (new work with an earlier deadline, or closing)."""
        ...

    def close(self) -> None:
        """Release what the channel itself holds (not the port)."""
        ...


class FdChannel:
    """A POSIX tty or pty by its descriptor: one select and one read per burst; a self-pipe wakes a read."""

    def __init__(self, fd: int, clock: Clock = time.monotonic) -> None:
        self.fd = fd
        self.clock = clock
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)

    def read(self, timeout_s: float | None) -> bytes:
        ready, _, _ = select.select([self.fd, self._wake_r], [], [], timeout_s)
        if not ready:
            return b""
        if self._wake_r in ready:
            try:
                os.read(self._wake_r, 512)
            except BlockingIOError:
                pass
            if self.fd not in ready:
                return b""
        data = os.read(self.fd, 4096)
        if not data:
            raise OSError("end of file: the device went away")
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        view = memoryview(data)
        end = self.clock() + timeout_s
        while view:
            try:
                view = view[os.write(self.fd, view) :]
            except BlockingIOError:
                left = end - self.clock()
                if left <= 0 or not select.select([], [self.fd], [], left)[1]:
                    raise TimeoutError(
                        f"the port took no data for {timeout_s:g} s (the printer is not reading)"
                    ) from None

    def wake(self) -> None:
        try:
            os.write(self._wake_w, b"!")
        except (BlockingIOError, OSError):
            pass  # a full pipe wakes the reader already; a closed one has no reader

    def close(self) -> None:
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass


class SerialChannel:
    """Any pyserial-like object, through its own read/write. Its reads wait up to the port's own timeout
    (set once: changing a pyserial timeout reconfigures the port), so the reader checks deadlines at
    least that often; writes honour the write timeout through pyserial's `write_timeout`."""

    def __init__(self, port: SerialPort) -> None:
        self.port = port
        self._write_timeout_s: float | None = None

    def read(self, timeout_s: float | None) -> bytes:
        port = self.port
        data = port.read(port.in_waiting or 1)
        if data and port.in_waiting:  # the rest of a burst that woke us: handle it as one chunk
            data += port.read(port.in_waiting)
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        port: Any = self.port
        if self._write_timeout_s != timeout_s:
            self._write_timeout_s = timeout_s
            if hasattr(port, "write_timeout"):
                port.write_timeout = timeout_s
        try:
            written = port.write(data)
        except Exception as exc:
            if type(exc).__name__ == "SerialTimeoutException":  # pyserial's: the port took nothing in time
                raise TimeoutError(f"the port took no data for {timeout_s:g} s (the printer is not reading)") from exc
            raise
        if written is not None and written < len(data):  # pyserial returns short only on its write timeout
            raise TimeoutError(f"the port took {written} of {len(data)} bytes in {timeout_s:g} s")

    def wake(self) -> None:
        cancel = getattr(self.port, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # noqa: BLE001 - a port that cannot cancel times out within its own timeout
                pass

    def close(self) -> None:
        pass


def channel_for(port: SerialPort, clock: Clock = time.monotonic) -> Channel:
    """The raw descriptor for an open pyserial POSIX port, pyserial's API for anything else."""
    try:
        from serial.serialposix import Serial as PosixSerial
    except ImportError:  # Windows
        return SerialChannel(port)
    if type(port) is PosixSerial and port.is_open and port.fd is not None:
        return FdChannel(port.fd, clock)
    return SerialChannel(port)

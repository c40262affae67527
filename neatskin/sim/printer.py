"""SimulatedPrinter: the simulated Marlin printer, served on a real pseudo-terminal or in-process.

`start_pty()` returns a `/dev/pts/N` path that any host (our driver through pyserial, Printrun,
a terminal) opens like a USB port; a thread serves it. A real board with auto-reset reboots on the DTR pulse of
every open; the pty has no DTR, so: a host that opens the port after the last one closed it (sim.pty.OpenWatch,
inotify) finds the printer booted again (`start`, the banner, unhomed, M155 off), and a printer halted by M112
also resets at the flush of its input that pyserial's `open()` makes (sim.pty's packet mode), even without the
watch. A host that opens without flushing a printer halted under it (a terminal program) finds it halted:
`reset()`, or the CLI's SIGUSR1 (docs/marlin.md). `serial()` returns a pyserial-compatible
object for in-process use without a pty. Both wrap one MarlinCore (firmware.py) under a lock,
so `probe_position()`, `now_s()` and `executed` may be read from any thread while it runs.
"""

from __future__ import annotations

import os
import threading
import time

from neatskin.gcode.profile import PrinterProfile, load_printer_profile
from neatskin.sim.faults import FaultConfig
from neatskin.sim.firmware import MarlinCore, ScaledClock, VirtualClock
from neatskin.sim.motion import Segment
from neatskin.sim.pty import OpenWatch, PtyPair, open_pty, open_watch, read_packet, write_all
from neatskin.tomlfile import resolve_path

# A host that opens the port after the last one closed it finds the printer booted again (power-on state: unhomed,
# M155 off, line 0), as a board that the open's DTR pulse resets. The boot happens at the open's flush (pyserial),
# the host's first bytes, or this long after the open (a host that does not flush sees the banner then).
OPEN_RESET_S = 0.1


class SimulatedPrinter:
    """A Marlin printer in software. time_mode "virtual" (no sleeping) or "scaled" (real time x speed).

    Its memory is bounded: it keeps the latest `history_lines` executed commands and clip events
    and the latest `keep_segments` moves (about 1,000 paper presses), however long it runs."""

    def __init__(
        self,
        profile: PrinterProfile,
        seed: int = 0,
        faults: FaultConfig = FaultConfig(),
        *,
        time_mode: str = "virtual",
        speed: float = 1.0,
        advanced_ok: bool = False,
        marlin_version: str = "2.1",
        ok_after_resend: bool = True,
        no_motion_before_homing: bool = False,
        rx_buffer_size: int | None = None,
        history_lines: int = 10_000,
        keep_segments: int = 4096,
    ) -> None:
        if time_mode not in ("virtual", "scaled"):
            raise ValueError(f"time_mode must be 'virtual' or 'scaled', got {time_mode!r}")
        clock = VirtualClock() if time_mode == "virtual" else ScaledClock(speed)
        self.profile = profile
        self.time_mode = time_mode
        self.core = MarlinCore(
            profile,
            seed=seed,
            faults=faults,
            clock=clock,
            advanced_ok=advanced_ok,
            marlin_version=marlin_version,
            ok_after_resend=ok_after_resend,
            no_motion_before_homing=no_motion_before_homing,
            rx_buffer_size=rx_buffer_size,
            history_lines=history_lines,
            keep_segments=keep_segments,
        )
        self.lock = threading.Condition(threading.RLock())
        self._pty: PtyPair | None = None
        self._watch: OpenWatch | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ---- what the rest of the rig reads --------------------------------------------------

    def now_s(self) -> float:
        """The printer's clock (virtual seconds, or scaled real seconds since it started)."""
        with self.lock:
            return self.core.clock.now()

    def probe_position(self, t_s: float | None = None) -> tuple[float, float, float]:
        """Where the probe is (x, y, z) in printer mm at time t_s on the printer's clock (default: now)."""
        with self.lock:
            return self.core.timeline.position_mm(self.core.clock.now() if t_s is None else t_s)

    def segments(self, t0_s: float = 0.0) -> list[Segment]:
        """The moves (sim.motion.Segment) from the one the probe rests after at t0_s onwards, in order.

        The printer keeps its latest moves only (MarlinCore's `keep_segments`); a t0_s older than
        those raises HistoryForgotten. `forget_before(t0_s)` says nothing before t0_s will be asked."""
        with self.lock:
            return self.core.timeline.segments_from(t0_s)

    def forget_before(self, t_s: float) -> int:
        """Drop the moves that ended before printer time t_s (the one the probe rests after stays)."""
        with self.lock:
            return self.core.timeline.forget_before(t_s)

    @property
    def executed(self) -> list[tuple[int | None, str]]:
        """(line number, command) of the commands the firmware executed, in order: the latest
        `history_lines` of them (MarlinCore); `executed_count` counts them all."""
        with self.lock:
            return list(self.core.executed)

    @property
    def executed_count(self) -> int:
        with self.lock:
            return self.core.executed_count

    @property
    def clip_events(self) -> list:
        with self.lock:
            return list(self.core.clip_events)

    def reset(self) -> None:
        """Press the reset button: `start` is sent, counters and homing are lost."""
        with self.lock:
            self.core.reset()
            self.lock.notify_all()

    # ---- transports ----------------------------------------------------------------------

    def start_pty(self) -> str:
        """Serve on a new raw pseudo-terminal from a thread; returns the path a host opens."""
        if self._pty is not None:
            return self._pty.path
        self._pty = open_pty(packet=True)  # the boot banner waits in the pty for a host that does not flush it
        self._watch = open_watch(self._pty.path)  # every host's open and close of the port (None: no inotify)
        self._thread = threading.Thread(target=self._serve, name=f"sim-printer {self._pty.path}", daemon=True)
        self._thread.start()
        return self._pty.path

    def _serve(self) -> None:
        # the hot path: one lock hold, one select, one read and at most one write per round
        pty = self._pty
        assert pty is not None
        core, lock, fd, stop, watch = self.core, self.lock, pty.master_fd, self._stop, self._watch
        data = b""
        opened = False
        last_s = time.monotonic()
        hosts, left, boot_at = 0, False, None  # hosts holding the port; the last one closed it; when to boot
        watched = False
        while not stop.is_set():
            events = watch.events() if watched and watch is not None else ()
            with lock:
                now_s = time.monotonic()
                core.idle(now_s - last_s)  # M155's reports go on while idle, in virtual time too
                last_s = now_s
                for change in events:
                    if change > 0 and hosts == 0 and left:  # a host opens the port another one closed
                        boot_at = now_s + OPEN_RESET_S
                    hosts = max(hosts + change, 0)
                    left = left or (change < 0 and hosts == 0)
                if boot_at is not None and (opened or data or now_s >= boot_at):
                    boot_at, left, opened = None, False, False  # as a board auto-reset by the open's DTR pulse
                    core.reset()
                    lock.notify_all()
                if opened and core.halted:  # a host opened the port: a halted board reboots (auto-reset)
                    core.reset()
                    lock.notify_all()
                if data:
                    core.receive(data)
                wait = core.step()
                out = core.take_output() if core.out else b""
                closed = core.closed
            try:
                if out:
                    write_all(fd, out)
                if closed:
                    break
                timeout_s = 0.05 if wait is None or wait > 0.05 else wait
                if boot_at is not None:  # a boot due without a flush or data: wake for it
                    timeout_s = min(timeout_s, max(boot_at - time.monotonic(), 0.0))
                data, opened, watched = read_packet(fd, timeout_s, watch)
            except OSError:
                break
        pty.close()
        if watch is not None:
            watch.close()

    def serial(self) -> SimSerial:
        """A pyserial-compatible port object talking to this printer in-process (no pty)."""
        return SimSerial(self)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._pty is not None:
            self._pty.close()
            self._pty = None

    def __enter__(self) -> SimulatedPrinter:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class SimSerial:
    """The subset of pyserial's Serial that hosts use: open/close, read/write, timeout, in_waiting."""

    def __init__(self, printer: SimulatedPrinter) -> None:
        self._printer = printer
        self._buffer = bytearray()
        self.timeout: float | None = 1.0
        self.is_open = False
        self.name = self.port = "sim://marlin"
        self.baudrate = printer.profile.baud_rate
        self._cancel = False

    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False
        with self._printer.lock:
            self._printer.lock.notify_all()

    def _check(self) -> None:
        import serial

        if not self.is_open:
            raise serial.PortNotOpenError()
        if self._printer.core.closed:
            raise serial.SerialException("the simulated printer closed the port")

    def _pull(self) -> float | None:
        wait = self._printer.core.step()
        self._buffer += self._printer.core.take_output()
        return wait

    def write(self, data: bytes) -> int:
        with self._printer.lock:
            self._check()
            self._printer.core.receive(bytes(data))
            self._pull()
            self._printer.lock.notify_all()
        return len(data)

    @property
    def in_waiting(self) -> int:
        with self._printer.lock:
            self._check()
            self._pull()
            return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        end = None if self.timeout is None else time.monotonic() + self.timeout
        lock = self._printer.lock
        with lock:
            while True:
                self._check()
                wait = self._pull()
                if len(self._buffer) >= size or (self._buffer and self.timeout == 0) or self._cancel:
                    break
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    break
                lock.wait(min(x for x in (left, wait, 0.05) if x is not None))
            self._cancel = False
            data = bytes(self._buffer[:size])
            del self._buffer[:size]
            return data

    def reset_input_buffer(self) -> None:
        with self._printer.lock:
            self._pull()
            self._buffer.clear()

    def cancel_read(self) -> None:
        with self._printer.lock:
            self._cancel = True
            self._printer.lock.notify_all()

    def flush(self) -> None:
        pass

    def fileno(self) -> int:  # pragma: no cover - hosts that select() need a real pty: use start_pty()
        raise OSError("the in-process simulated port has no file descriptor; use start_pty()")


def sim_printer_for_tests(profile_path: str | os.PathLike | None = None, **kwargs) -> SimulatedPrinter:
    """A simulated printer on the repository's paper profile (or the given one)."""
    from pathlib import Path

    path = Path(profile_path) if profile_path else resolve_path("protocols/printers/paper.toml")
    return SimulatedPrinter(load_printer_profile(path), **kwargs)

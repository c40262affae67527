"""MarlinDriver: exactly-once, in-order G-code delivery to Marlin over any pyserial port object.

One reader thread owns the protocol: it reads replies, retires lines on `ok`, replays on
`Resend:`, sends the next queued line the moment an `ok` frees the line (no thread hand-off per
line), extends deadlines on `busy:`, and recovers a lost `ok` by a probe: `N<n+1> M118 E1
neatskin-probe <n+1>`. The firmware either echoes the probe (so every line up to it ran: the
`ok` was lost) or rejects its number with `Resend: n` (so line n never arrived and is replayed):
no line is ever sent twice under a number the firmware has already taken. Callers block in
`send` / `send_lines`; every wait has a deadline. Halts, resets and a dead port raise a
MarlinError naming the last line acknowledged; after that nothing is sent but an M112 on request.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterable
from os import PathLike

from neatskin.gcode.parse import parse_line
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import errors as E
from neatskin.marlin.deadlines import MotionTracker
from neatskin.marlin.linestate import DriverConfig, LineProtocol, _Job, _Line  # noqa: F401 (re-exported)
from neatskin.marlin.replies import Position, parse_m114, parse_m119
from neatskin.marlin.wirelog import WireLog


class MarlinDriver(LineProtocol):
    """Talk to Marlin over `port` (an unopened or open pyserial object: Serial, serial_for_url(...))."""

    def __init__(
        self,
        port,
        *,
        config: DriverConfig = DriverConfig(),
        profile: PrinterProfile | None = None,
        wire_log: str | PathLike | None = None,
    ) -> None:
        self.port = port
        self.config = config
        self.profile = profile
        self.wire_log_path = wire_log
        self._wire: WireLog | None = None
        self._lock = threading.RLock()
        self._wlock = threading.Lock()
        self._reader: threading.Thread | None = None
        self._stop = threading.Event()
        self._reset_state()

    @classmethod
    def open(cls, url: str, baud_rate: int = 115200, **kwargs) -> MarlinDriver:
        """A driver on a port name or pyserial URL (`/dev/ttyUSB0`, `/dev/pts/3`, `loop://`, `socket://h:p`)."""
        import os

        import serial

        if "://" not in url and not os.path.exists(url):
            raise E.PortMissing("the device does not exist", port=url)
        try:
            port = serial.serial_for_url(url, baudrate=baud_rate, timeout=0.02, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise E.PortDead(f"cannot use port {url!r}: {exc}", port=url) from exc
        return cls(port, **kwargs)

    # ---- state --------------------------------------------------------------------------

    def _reset_state(self) -> None:
        self._next_n = 0
        self._queue: collections.deque[_Job] = collections.deque()
        self._inflight: list[_Line] = []
        self._failure: E.MarlinError | None = None
        self._session = False
        self._booted = False
        self._last_acked: tuple[int | None, str | None] = (None, None)
        self._acked_jobs = 0
        self._comm_errors = 0
        self._fw_last_line: tuple[int, int] | None = None  # (Last Line: L, comm error count when said)
        self._history: dict[int, _Line] = {}  # recently acknowledged lines, for a firmware that never took them
        self._stale_streak = 0
        self._served = (None, -1, 0.0)  # (n, comm_errors at serve, time)
        self._pending_resend: int | None = None
        self._resend_due = 0.0
        self._swallow_ok = False
        self._advanced_ok_seen = False
        self._ok_follows_resend = False  # learned: Marlin 1.x sends `ok` after `Resend:`, 2.x does not
        self._resends_without_ok = 0
        self._resend_counts: collections.Counter[int] = collections.Counter()
        self._probes_in_stall = 0
        self._motion = MotionTracker(self.profile, self.config.homing_time_s, self.config.default_feed_mm_s)
        self._motion_end = 0.0
        self.unsolicited: collections.deque[str] = collections.deque(maxlen=200)
        self.actions: list[str] = []
        self.stats = collections.Counter()

    @property
    def port_name(self) -> str:
        return str(getattr(self.port, "name", None) or getattr(self.port, "port", None) or "<port>")

    @property
    def last_acknowledged(self) -> tuple[int | None, str | None]:
        """(line number, command) of the last line the firmware acknowledged."""
        return self._last_acked

    # ---- connect / close ----------------------------------------------------------------

    def connect(self, boot_timeout_s: float | None = None) -> MarlinDriver:
        """Open the port, wait for `start` (or time out cleanly), and reset the line counter (M110 N0)."""
        import serial

        self._stop_reader()
        self._reset_state()
        if self.wire_log_path is not None and self._wire is None:
            self._wire = WireLog(self.wire_log_path)
        try:
            if not self.port.is_open:
                self.port.open()
            self.port.timeout = self.config.poll_s
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise E.PortDead(f"cannot open: {exc}", port=self.port_name) from exc
        self._stop.clear()
        self._reader = threading.Thread(target=self._run, name=f"marlin-reader {self.port_name}", daemon=True)
        self._reader.start()
        wait_s = self.config.boot_timeout_s if boot_timeout_s is None else boot_timeout_s
        end = time.monotonic() + wait_s
        while time.monotonic() < end and not self._booted and self._failure is None:
            time.sleep(0.005)
        if self._booted:  # let the boot banner finish before talking
            time.sleep(min(0.05, wait_s))
        job = _Job("M110 N0")
        with self._lock:
            self._raise_failure()
            self._send_line(job, m110=True)
        self._wait(job)
        with self._lock:
            self._session = True
        return self

    def reconnect(self, boot_timeout_s: float | None = None) -> MarlinDriver:
        """After a PrinterReset (or any failure): start a new session. The printer must be homed again."""
        return self.connect(boot_timeout_s)

    def close(self) -> None:
        self._stop_reader()
        try:
            self.port.close()
        except Exception:  # noqa: BLE001 - closing a dead port must not raise
            pass
        if self._wire is not None:
            self._wire.close()
            self._wire = None

    def __enter__(self) -> MarlinDriver:
        return self.connect() if self._reader is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    def _stop_reader(self) -> None:
        if self._reader is None:
            return
        self._stop.set()
        cancel = getattr(self.port, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # noqa: BLE001
                pass
        self._reader.join(timeout=2.0)
        self._reader = None
        with self._lock:
            if self._failure is None:
                self._failure = E.PortDead(
                    "the driver was closed",
                    last_line=self._last_acked[0],
                    last_command=self._last_acked[1],
                    port=self.port_name,
                )
            self._fail_jobs(self._failure)

    # ---- public API ---------------------------------------------------------------------

    def send(self, command: str, *, strict: bool = True) -> list[str]:
        """Send one command and wait for its `ok`; the reply lines before the `ok` (M114 text, echoes).

        strict: raise CommandRejected when Marlin refuses it (`Unknown command`, `Home XYZ First`).
        """
        command = _clean(command)
        job = _Job(command)
        with self._lock:
            self._raise_failure()
            self._queue.append(job)
            self._pump(time.monotonic())
        self._wait(job)
        if strict and job.rejected:
            raise E.CommandRejected(
                f"{job.rejected!r} in answer to N{job.line} {command!r}",
                last_line=job.line,
                last_command=command,
                port=self.port_name,
            )
        return job.replies

    def send_lines(
        self, lines: Iterable[str], progress: Callable[[int, int], None] | None = None, *, source: str = "<lines>"
    ) -> int:
        """Send a program in order, exactly once each; returns the number of commands sent.

        Comments and blank lines are dropped; every line is parsed first, so a syntax error
        raises before anything is sent. progress(done, total) is called as lines are acknowledged.
        A refused command stops the batch (CommandRejected) with the rest unsent.
        """
        from neatskin.gcode.parse import parse_program

        text = "\n".join(lines)
        program = parse_program(text, source=source)
        cleaned = [(_clean(line.raw), line) for line in program]
        cleaned = [(c, line) for c, line in cleaned if c]
        if not cleaned:
            return 0
        batch = object()
        jobs = [_Job(c, batch, line) for c, line in cleaned]
        with self._lock:
            self._raise_failure()
            start = self._acked_jobs
            self._queue.extend(jobs)
            self._pump(time.monotonic())
        last = jobs[-1]
        while not last.event.wait(0.1):
            self._check_reader()
            if progress is not None:
                progress(min(self._acked_jobs - start, len(jobs)), len(jobs))
        self._wait(last)
        for job in jobs:
            if job.rejected:
                raise E.CommandRejected(
                    f"{job.rejected!r} in answer to N{job.line} {job.command!r}",
                    last_line=job.line,
                    last_command=job.command,
                    port=self.port_name,
                )
        if progress is not None:
            progress(len(jobs), len(jobs))
        return len(jobs)

    def sync(self) -> None:
        """M400: return when every queued move has finished."""
        self.send("M400")

    def position(self) -> Position:
        """M114, parsed."""
        return parse_m114(self.send("M114"))

    def endstops(self) -> dict[str, bool]:
        """M119, parsed: {"x_min": False, "z_min": True, ...} (True = triggered)."""
        return parse_m119(self.send("M119"))

    def emergency_stop(self) -> None:
        """Send M112 at once, ahead of anything queued; the session ends (EmergencyStopped)."""
        try:
            self._write(b"M112\n")
        finally:
            with self._lock:
                if self._failure is None:
                    n, cmd = self._last_acked
                    self._fail(
                        E.EmergencyStopped("M112 sent on request", last_line=n, last_command=cmd, port=self.port_name)
                    )

    # ---- waiting --------------------------------------------------------------------------

    def _wait(self, job: _Job) -> None:
        while not job.event.wait(0.25):
            self._check_reader()
        if job.error is not None:
            raise job.error

    def _check_reader(self) -> None:
        if self._reader is None or not self._reader.is_alive():
            with self._lock:
                if self._failure is None:
                    n, cmd = self._last_acked
                    self._fail(
                        E.PortDead("the reader thread stopped", last_line=n, last_command=cmd, port=self.port_name)
                    )

    def _raise_failure(self) -> None:
        if self._failure is not None:
            raise self._failure
        if self._reader is None:
            raise E.PortDead("not connected: call connect() first", port=self.port_name)


def _clean(command: str) -> str:
    """Drop a comment and surrounding blanks; refuse framing the driver adds itself."""
    text = command.split(";", 1)[0].strip()
    if "\n" in text or "\r" in text:
        raise ValueError(f"one command per call, got {command!r}")
    parsed = parse_line(text) if text else None
    if parsed is not None and (parsed.line_number is not None or parsed.checksum is not None):
        raise ValueError(f"send commands without N.. or *.. framing (the driver adds it), got {command!r}")
    return text

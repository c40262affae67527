"""The line protocol behind MarlinDriver: framing, `ok` accounting, resends, deadlines and lost-`ok` probes.

`LineProtocol` is the state machine the driver's reader thread runs; every method here is
called with the driver's lock held. It reads Marlin's replies (replies.classify), retires the
line in flight on `ok`, replays on `Resend:`, extends deadlines on `busy:`, sends the lost-`ok`
probe (`N<n+1> M118 E1 neatskin-probe <n+1>`) when a deadline passes, and turns halts, resets and
silence into MarlinErrors that name the last line acknowledged. See driver.py for the public API.
"""

from __future__ import annotations

import collections
import os
import select
import threading
import time
from dataclasses import dataclass

from neatskin.marlin import errors as E
from neatskin.marlin.replies import PROBE_TAG, Kind, classify, frame


@dataclass(frozen=True)
class DriverConfig:
    boot_timeout_s: float = 3.0  # wait this long for `start` after opening; then go on without it
    min_timeout_s: float = 2.0  # the least time any line may take to be acknowledged
    busy_extension_s: float = 6.0  # a `busy:` pushes the deadline to now + this (Marlin sends one every 2 s)
    max_busy_s: float = 900.0  # keep-alives cannot stretch one line's wait beyond this
    probe_attempts: int = 3  # lost-ok probes per stall before NoAnswer
    max_resends: int = 12  # the same line asked for this often -> ResendLoop
    resend_grace_s: float = 0.02  # wait for an `ok` that old Marlin sends after `Resend:` before replaying
    duplicate_resend_s: float = 1.0  # an identical `Resend: n` with no new error within this is a duplicate
    poll_s: float = 0.02  # the reader's read timeout: how often deadlines are checked
    write_timeout_s: float = 5.0  # a write that finds no room for this long: PortDead
    max_in_flight: int = 1  # >1 pipelines lines, only once the firmware's `ok N.. P.. B..` names them
    rx_buffer_bytes: int = 127  # Marlin's RX_BUFFER_SIZE less one: bytes in flight never exceed it
    homing_time_s: float = 60.0
    default_feed_mm_s: float = 25.0
    motion_time_scale: float = 1.0  # real seconds per second of motion: 0 for a virtual-time simulated printer

    def __post_init__(self) -> None:
        for name in ("boot_timeout_s", "min_timeout_s", "busy_extension_s", "max_busy_s", "poll_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"DriverConfig.{name} must be > 0")


class _Job:
    __slots__ = ("command", "replies", "event", "error", "rejected", "line", "batch", "parsed")

    def __init__(self, command: str, batch: object = None, parsed=None) -> None:
        self.command = command
        self.parsed = parsed  # the GcodeLine, when the caller parsed it already
        self.replies: list[str] = []
        self.event = threading.Event()
        self.error: BaseException | None = None
        self.rejected: str | None = None
        self.line: int | None = None
        self.batch = batch


class _Line:
    __slots__ = ("n", "command", "data", "job", "deadline", "hard_deadline", "probe", "echoed", "m110", "released")

    def __init__(self, n, command, data, job, deadline, probe=False, m110=False, max_busy_s=900.0):
        self.n, self.command, self.data, self.job = n, command, data, job
        self.deadline = deadline
        self.hard_deadline = deadline + max_busy_s
        self.probe, self.echoed, self.m110 = probe, False, m110
        self.released = False  # its caller was told it is acknowledged


_SYNCHRONISING = frozenset({"G28", "G4", "M400", "G29"})


def _posix_fd(port) -> int | None:
    """The descriptor of an open pyserial POSIX port (a /dev/tty* or a pty), for direct select/read/write.

    pyserial's own read and write add a select, an ioctl and timeout bookkeeping per call; on the
    one-line-in-flight path that is a third of the driver's time. Other port objects (socket://,
    loop://, the simulator's in-process port) go through pyserial's API.
    """
    try:
        from serial.serialposix import Serial as PosixSerial
    except ImportError:  # Windows
        return None
    if type(port) is PosixSerial and port.is_open and port.fd is not None:
        return port.fd
    return None


def _write_fd(fd: int, data: bytes, timeout_s: float) -> None:
    """All of data to a non-blocking descriptor, waiting for room at most timeout_s in all."""
    view = memoryview(data)
    end = time.monotonic() + timeout_s
    while view:
        try:
            view = view[os.write(fd, view) :]
        except BlockingIOError:
            left = end - time.monotonic()
            if left <= 0 or not select.select([], [fd], [], left)[1]:
                raise TimeoutError(f"the port took no data for {timeout_s:g} s (the printer is not reading)")


class LineProtocol:
    """The protocol state machine; MarlinDriver supplies the port, the lock and the state it resets."""

    # ---- writing (callers hold self._lock) ----------------------------------------------

    def _write(self, data: bytes) -> None:
        error = None
        with self._wlock:
            if self._wire is not None:
                self._wire.write(">", data)
            try:
                fd = _posix_fd(self.port)
                if fd is None:
                    self.port.write(data)
                else:
                    _write_fd(fd, data, self.config.write_timeout_s)
            except Exception as exc:  # noqa: BLE001 - any port failure is a dead port
                error = exc
        if error is not None:  # outside the write lock: the state lock is always taken first
            with self._lock:
                n, cmd = self._last_acked
                self._fail(E.PortDead(f"write failed: {error}", last_line=n, last_command=cmd, port=self.port_name))
            raise self._failure from error

    def _deadline(self, command, now: float) -> float:
        own_s, _ = self._motion.line_time_s(command)
        own_s *= self.config.motion_time_scale
        start = max(now, self._motion_end)  # a full planner delays any ok until queued motion runs out
        self._motion_end = start + own_s
        return self._motion_end + self.config.min_timeout_s

    def _send_line(self, job: _Job | None, *, probe: bool = False, m110: bool = False) -> _Line:
        now = time.monotonic()
        n = self._next_n
        self._next_n += 1
        command = f"M118 E1 {PROBE_TAG} {n}" if probe else job.command
        if job is not None:
            job.line = n
        if probe or m110:
            deadline = max(now, self._motion_end) + self.config.min_timeout_s
        else:
            deadline = self._deadline(job.parsed or command, now)
        line = _Line(n, command, frame(command, n), job, deadline, probe, m110, self.config.max_busy_s)
        self._inflight.append(line)
        self.stats["lines_sent"] += 1
        self.stats["max_in_flight"] = max(self.stats["max_in_flight"], len(self._inflight))
        self._write(line.data)
        return line

    def _pump(self, now: float) -> None:
        while self._queue and self._failure is None and self._pending_resend is None and self._room_for(self._queue[0]):
            self._send_line(self._queue.popleft())

    def _room_for(self, job: _Job) -> bool:
        """One line in flight; more (up to max_in_flight, within Marlin's RX buffer) only once the
        firmware's `ok N..` names its lines, and never past a probe or an M110."""
        if not self._inflight:
            return True
        if self.config.max_in_flight <= 1 or not self._advanced_ok_seen:
            return False
        if len(self._inflight) >= self.config.max_in_flight or any(l.probe or l.m110 for l in self._inflight):
            return False
        in_flight = sum(len(line.data) for line in self._inflight)
        return in_flight + len(job.command) + 16 <= self.config.rx_buffer_bytes

    # ---- the reader ---------------------------------------------------------------------

    def _run(self) -> None:
        buffer = b""
        port = self.port
        fd = _posix_fd(port)
        poll_s = self.config.poll_s
        while not self._stop.is_set():
            try:
                if fd is not None:  # a POSIX tty or pty: one select and one read per burst
                    ready, _, _ = select.select([fd], [], [], poll_s)
                    data = os.read(fd, 4096) if ready else b""
                    if ready and not data:
                        raise OSError("end of file: the device went away")
                else:
                    data = port.read(port.in_waiting or 1)
                    if data and port.in_waiting:  # the rest of a burst that woke us: handle it as one chunk
                        data += port.read(port.in_waiting)
            except Exception as exc:  # noqa: BLE001 - SerialException, OSError: the port is gone
                if not self._stop.is_set():
                    with self._lock:
                        n, cmd = self._last_acked
                        self._fail(
                            E.PortDead(f"read failed: {exc}", last_line=n, last_command=cmd, port=self.port_name)
                        )
                return
            now = time.monotonic()
            with self._lock:
                try:
                    if data:
                        if self._wire is not None:
                            self._wire.write("<", data)
                        buffer += data
                        *complete, buffer = buffer.split(b"\n")
                        for raw in complete:
                            if self._failure is not None:
                                break
                            self._on_line(raw.decode("ascii", "replace").strip(), now)
                    if self._failure is None:
                        self._tick(now)
                except E.MarlinError:
                    pass  # recorded in self._failure; waiters were woken

    def _on_line(self, text: str, now: float) -> None:
        if not text:
            return
        reply = classify(text)
        kind = reply.kind
        head = self._inflight[0] if self._inflight else None
        if kind is Kind.OK:
            self._on_ok(reply, now)
        elif kind is Kind.RESEND:
            self._on_resend(reply.number, now)
        elif kind is Kind.COMM_ERROR:
            self._comm_errors += 1
            self._fw_last_line = (reply.number, self._comm_errors)
            self.stats["comm_errors"] += 1
        elif kind in (Kind.HALTED, Kind.STOPPED):
            self._fail_here(E.PrinterHalted, f"the printer said {text!r}")
        elif kind is Kind.START:
            if self._session:
                self._fail_here(E.PrinterReset, "the printer sent 'start' (it rebooted)")
            else:
                self._booted = True
                if head is not None and head.m110:  # booted under our M110: say it again
                    self._pending_resend, self._resend_due = head.n, now
        elif kind is Kind.BUSY:
            self.stats["busy"] += 1
            for line in self._inflight:
                line.deadline = min(max(line.deadline, now + self.config.busy_extension_s), line.hard_deadline)
        elif kind is Kind.PROBE_ECHO:
            self._on_probe_echo(reply.number, now)
        elif kind is Kind.WAIT:
            pass
        else:
            if kind is Kind.ACTION:
                self.actions.append(text)
            if head is not None and head.job is not None:
                head.job.replies.append(text)
                if kind in (Kind.UNKNOWN_COMMAND, Kind.REJECTED):
                    head.job.rejected = text
            else:
                self.unsolicited.append(text)

    def _on_ok(self, reply, now: float) -> None:
        if self._swallow_ok:  # old Marlin: `Resend: n` then `ok`; this ok acknowledges nothing
            self._swallow_ok = False
            self._ok_follows_resend = True
            self.stats["oks_swallowed"] += 1
            return
        if not self._inflight:
            self.stats["stray_oks"] += 1
            return
        head = self._inflight[0]
        if reply.number is not None:  # ADVANCED_OK names the line
            self._advanced_ok_seen = True
            if reply.number < head.n:
                self.stats["stale_oks"] += 1
                return
            while self._inflight and self._inflight[0].n <= reply.number:
                self._retire(self._inflight[0])
        elif head.probe and not head.echoed:
            # the firmware echoes a probe before its ok: this ok is a duplicate of an earlier one
            self.stats["stray_oks"] += 1
            return
        else:
            self._retire(head)
        # the next line goes out in _tick, after the whole chunk is read: a duplicated `ok` in the
        # same chunk then finds nothing in flight instead of acknowledging a line just sent

    def _retire(self, line: _Line) -> None:
        self._inflight.remove(line)
        self._probes_in_stall = 0
        self._stale_streak = 0
        self._history[line.n] = line
        self._history.pop(line.n - 128, None)
        if line.released:  # acknowledged again after a rewind: its caller already went on
            return
        line.released = True
        self._resend_counts.pop(line.n, None)
        if not line.probe:
            self._last_acked = (line.n, line.command)
        if line.command.split(" ", 1)[0] in _SYNCHRONISING:  # its ok means the planner ran empty
            self._motion_end = min(self._motion_end, time.monotonic())
        job = line.job
        if job is not None:
            self._acked_jobs += 1
            if job.rejected and job.batch is not None:
                self._cancel_batch(job)
            job.event.set()

    def _cancel_batch(self, job: _Job) -> None:
        rest = [j for j in self._queue if j.batch is job.batch]
        self._queue = collections.deque(j for j in self._queue if j.batch is not job.batch)
        for other in rest:
            other.error = E.CommandRejected(
                f"not sent: N{job.line} {job.command!r} was refused ({job.rejected!r})",
                last_line=job.line,
                last_command=job.command,
                port=self.port_name,
            )
            other.event.set()

    def _grace_s(self) -> float:
        """Wait for an `ok` after `Resend:` until the firmware has shown, three times, that it sends none."""
        if self._ok_follows_resend or self._resends_without_ok < 3:
            return self.config.resend_grace_s
        return 0.0

    def _on_resend(self, n: int, now: float) -> None:
        self.stats["resend_requests"] += 1
        if not self._inflight:
            self.stats["stale_resends"] += 1
            return
        head = self._inflight[0]
        if head.m110:
            self._pending_resend, self._resend_due, self._swallow_ok = head.n, now + self._grace_s(), True
            return
        fresh = (
            self._fw_last_line is not None
            and self._fw_last_line[0] == n - 1
            and self._fw_last_line[1] > self._served[1]
        )
        if n > self._inflight[-1].n:  # it has every line in flight: nothing to replay
            self.stats["stale_resends"] += 1
            while fresh and self._inflight and self._inflight[0].probe:
                self._retire(self._inflight[0])  # a probe it took (its echo went missing) is done
            return
        if n < head.n:
            if fresh and all(m in self._history for m in range(n, head.n)):
                # the firmware says it never took lines we counted as acknowledged (a duplicated ok):
                # they are replayed under their own numbers, so nothing runs twice
                self.stats["rewinds"] += 1
                self._inflight[:0] = [self._history.pop(m) for m in range(n, head.n)]
            else:
                self.stats["stale_resends"] += 1
                self._stale_streak += 1
                if self._stale_streak > self.config.max_resends:
                    self._fail_here(E.ResendLoop, f"the printer keeps asking for N{n}, acknowledged before")
                return
        served_n, served_errors, served_at = self._served
        if n == served_n and self._comm_errors == served_errors and now - served_at < self.config.duplicate_resend_s:
            self.stats["duplicate_resends"] += 1
            return
        if self._pending_resend is not None and self._pending_resend <= n:
            self.stats["duplicate_resends"] += 1
            return
        self._resend_counts[n] += 1
        if self._resend_counts[n] > self.config.max_resends:
            self._fail_here(E.ResendLoop, f"line N{n} was asked for {self._resend_counts[n]} times")
            return
        self._pending_resend, self._resend_due, self._swallow_ok = n, now + self._grace_s(), True
        self._served = (n, self._comm_errors, now)

    def _on_probe_echo(self, k: int, now: float) -> None:
        probe = next((line for line in self._inflight if line.n == k and line.probe), None)
        if probe is None:
            self.stats["stale_probe_echoes"] += 1
            return
        self.stats["oks_recovered"] += sum(1 for line in self._inflight if line.n < k)
        for line in [line for line in self._inflight if line.n < k]:
            self._retire(line)  # the firmware ran the probe, so it ran every line before it
        probe.echoed = True
        probe.deadline = now + self.config.min_timeout_s

    def _tick(self, now: float) -> None:
        if self._pending_resend is not None and now >= self._resend_due:
            n = self._pending_resend
            self._pending_resend = None
            if self._swallow_ok:
                self._resends_without_ok += 1
            self._swallow_ok = False
            for line in self._inflight:
                if line.n >= n or line.m110:
                    self.stats["lines_resent"] += 1
                    line.deadline = max(line.deadline, now + self.config.min_timeout_s)
                    self._write(line.data)
            self._served = (n, self._comm_errors, now)
        if not self._inflight:
            self._pump(now)
            return
        head = self._inflight[0]
        if now < head.deadline or self._pending_resend is not None:
            return
        if head.probe and head.echoed:  # the probe ran; its own ok was lost
            self.stats["oks_recovered"] += 1
            self._retire(head)
            self._pump(now)
            return
        if head.m110:  # M110 is idempotent: say it again
            self._resend_counts[head.n] += 1
            if self._resend_counts[head.n] > self.config.probe_attempts:
                self._fail_here(
                    E.NoAnswer,
                    f"no answer to {head.command!r} within {self.config.min_timeout_s:g} s, "
                    f"{self.config.probe_attempts} times",
                )
                return
            head.deadline = now + self.config.min_timeout_s
            self._write(head.data)
            return
        if self._probes_in_stall >= self.config.probe_attempts:
            self._fail_here(
                E.NoAnswer, f"no ok for N{head.n} {head.command!r} and no answer to {self._probes_in_stall} probes"
            )
            return
        self._probes_in_stall += 1
        self.stats["probes"] += 1
        pending = next((line for line in self._inflight if line.probe), None)
        if pending is not None:  # the probe itself went missing: say it again under its number
            pending.deadline = max(now, self._motion_end) + self.config.min_timeout_s
            self._write(pending.data)
            probe = pending
        else:
            probe = self._send_line(None, probe=True)
        for line in self._inflight:
            line.deadline = max(line.deadline, probe.deadline)

    # ---- failure --------------------------------------------------------------------------

    def _fail_here(self, kind: type[E.MarlinError], detail: str) -> None:
        n, cmd = self._last_acked
        self._fail(kind(detail, last_line=n, last_command=cmd, port=self.port_name))

    def _fail(self, error: E.MarlinError) -> None:
        if self._failure is None:
            self._failure = error
        self._fail_jobs(self._failure)

    def _fail_jobs(self, error: E.MarlinError) -> None:
        jobs = [line.job for line in self._inflight if line.job is not None] + list(self._queue)
        self._queue.clear()
        self._inflight.clear()
        for job in jobs:
            if job.error is None:
                job.error = error
            job.event.set()

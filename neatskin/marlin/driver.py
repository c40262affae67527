"""MarlinDriver: exactly-once, in-order G-code delivery to Marlin over any pyserial port object.

The driver is the thin transport around the sans-IO `LineProtocol` (linestate.py): it owns the
port (through one `Channel`, transport.py), a reader thread that feeds the protocol what it
reads and the time, the writes the protocol asks for, the wire log, and the callers who block
in `send` / `send_lines` until their jobs finish. All protocol decisions (resends, lost-`ok`
probes, deadlines, caps) live in the state machine; every wait here ends when the protocol
finishes or fails the job, and the protocol has a deadline for every line. Halts, resets and a
dead port raise a MarlinError naming the last line acknowledged; after that nothing is sent but
an M112 on request.
"""

from __future__ import annotations

import collections
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable
from os import PathLike
from typing import Any

from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import errors as E
from neatskin.marlin.commands import CommandParser, clean_command
from neatskin.marlin.jobs import Acknowledged, DriverConfig, Event, Failed, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.marlin.replies import Position, parse_m114, parse_m119
from neatskin.marlin.transport import Channel, Clock, SerialPort, channel_for
from neatskin.marlin.wirelog import WireLog

__all__ = ["DriverConfig", "MarlinDriver"]

log = logging.getLogger(__name__)
READER_STANDBY_S = 0.25  # the reader stands by this long after a caller waited (wall seconds: thread scheduling)


class MarlinDriver:
    """Talk to Marlin over `port` (an unopened or open pyserial object: Serial, serial_for_url(...))."""

    def __init__(
        self,
        port: SerialPort,
        *,
        config: DriverConfig = DriverConfig(),
        profile: PrinterProfile | None = None,
        wire_log: str | PathLike[str] | None = None,
        clock: Clock = time.monotonic,
        rx_buffer_size: int | None = None,
    ) -> None:
        """rx_buffer_size: the firmware's RX_BUFFER_SIZE (the printer profile's `rx_buffer_size`; default:
        the profile's, else Marlin's stock 128): lines and probes in flight never hold more bytes."""
        self.port = port
        self.config = config
        self.profile = profile
        self.wire_log_path = wire_log
        self.clock = clock
        self._wire: WireLog | None = None
        lock = threading.RLock()
        self._cond = threading.Condition(lock)
        self._reader: threading.Thread | None = None
        self._channel: Channel | None = None
        self._stop = threading.Event()
        self._protocol = LineProtocol(config, profile, self.port_name, rx_buffer_size=rx_buffer_size)
        self._batch: list[Job] = []
        # what callers block on: the reader wakes them only when one of these finished (or the session
        # failed, or a drain ended), not for every `ok` of a batch: a waiter woken per line competes with
        # the reader for the lock and the GIL on the hot path
        self._awaited: list[Job] = []
        self._results: dict[Job, Event] = {}  # how each job ended, from the protocol's events, until read
        self._commands = CommandParser()
        self._draining = 0
        self._reader_running = False
        self._asleep = False  # the thread reading is in a read that ends at _sleeping_until (None: on data or wake())
        self._sleeping_until: float | None = None
        self.reader_wakeups = 0  # reads that ended (data, a deadline, a wake): nobody polls
        self.caller_reads = 0  # of them, those a waiting caller made (the rest are the reader thread's)
        # the read right: one thread at a time reads the channel and feeds the protocol (bytes stay in order). A
        # caller blocked on its job takes it when it is free and reads its own replies: a round trip then wakes
        # the printer's side and the caller, not a reader thread in between (a thread hand-off per command costs
        # a context switch and a GIL hand-off; on a loaded 2-core machine a wake-up can wait a time slice)
        self._reading = False
        self._park = threading.Condition(lock)  # where the reader stands by
        self._callers_seen_s = -1e9  # time.monotonic() when a caller last waited: the reader stands by after it
        self._progress_waiters = 0
        self._progress_at = 0.0

    @classmethod
    def open(cls, url: str, baud_rate: int = 115200, **kwargs: Any) -> MarlinDriver:
        """A driver on a port name or pyserial URL (`/dev/ttyUSB0`, `/dev/pts/3`, `loop://`, `socket://h:p`).

        A device port is opened exclusively (flock): a second process gets PortBusy, not a shared line."""
        import serial

        if "://" not in url and not os.path.exists(url):
            raise E.PortMissing("the device does not exist", port=url)
        try:
            port = serial.serial_for_url(url, baudrate=baud_rate, timeout=0.02, exclusive=True, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise E.PortDead(f"cannot use port {url!r}: {exc}", port=url) from exc
        return cls(port, **kwargs)

    # ---- what callers read ------------------------------------------------------------------

    @property
    def port_name(self) -> str:
        return str(getattr(self.port, "name", None) or getattr(self.port, "port", None) or "<port>")

    @property
    def stats(self) -> collections.Counter[str]:
        """Counters of this session: lines_sent, lines_resent, probes, busy, oks_swallowed, stray_oks..."""
        return self._protocol.stats

    @property
    def last_acknowledged(self) -> tuple[int | None, str | None]:
        """(line number, command) of the last line the firmware acknowledged."""
        return self._protocol.last_acked

    @property
    def actions(self) -> list[str]:
        return self._protocol.actions

    @property
    def unsolicited(self) -> collections.deque[str]:
        return self._protocol.unsolicited

    @property
    def commanded_position_mm(self) -> tuple[float | None, float | None, float | None]:
        """Where the lines sent so far put the tool (None: unknown), from the host's motion model."""
        x, y, z = list(self._protocol.motion.position_mm or [None, None, None])[:3]
        return x, y, z

    @property
    def commanded_absolute(self) -> bool:
        """Whether the lines sent so far leave the printer in absolute (G90) distance mode."""
        return bool(self._protocol.motion.absolute)

    @property
    def lines_in_flight(self) -> int:
        """Lines written whose `ok` has not come yet."""
        return self._protocol.in_flight

    @property
    def failure(self) -> E.MarlinError | None:
        """The error that ended the session, if any."""
        return self._protocol.failure

    # ---- connect / close ----------------------------------------------------------------------

    def connect(self, boot_timeout_s: float | None = None) -> MarlinDriver:
        """Open the port, wait for `start` (or time out cleanly), and reset the line counter (M110 N0).

        Bounded: a boot loop or a printer that refuses M110 ends in ConnectFailed, silence in NoAnswer."""
        import serial

        self._stop_reader()
        if self.wire_log_path is not None and self._wire is None:
            try:
                self._wire = WireLog(self.wire_log_path, clock=self.clock)
            except OSError as exc:
                raise E.WireLogFailed(f"{self.wire_log_path}: {exc}", port=self.port_name) from exc
        try:
            if not self.port.is_open:
                self.port.open()
            self.port.timeout = self.config.poll_s
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            if "exclusively lock" in str(exc) or "Resource temporarily unavailable" in str(exc):
                raise E.PortBusy(f"cannot open it exclusively: {exc}", port=self.port_name) from exc
            raise E.PortDead(f"cannot open: {exc}", port=self.port_name) from exc
        self._channel = channel_for(self.port, self.clock)
        with self._cond:
            hello = self._protocol.start_session(self.clock(), boot_timeout_s)
            self._flush()
        self._stop.clear()
        self._reader_running = True
        self._reader = threading.Thread(target=self._run, name=f"marlin-reader {self.port_name}", daemon=True)
        self._reader.start()
        self._wait(hello)
        self._results.pop(hello, None)
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

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _stop_reader(self) -> None:
        if self._reader is None:
            return
        self._stop.set()
        with self._cond:
            self._park.notify_all()
        if self._channel is not None:
            self._channel.wake()
        self._reader.join(timeout=2.0)
        with self._cond:  # a caller in a read ends it at the wake (or its deadline) before the channel closes
            self._cond.wait_for(lambda: not self._reading, timeout=2.0)
        self._reader = None
        if self._channel is not None:
            self._channel.close()
        with self._cond:
            n, cmd = self._protocol.last_acked
            self._protocol.fail(E.PortDead("the driver was closed", last_line=n, last_command=cmd, port=self.port_name))
            self._cond.notify_all()

    # ---- the transport: the reader thread and the writes --------------------------------------

    def _run(self) -> None:
        """Read, feed the protocol, write what it asks for; sleep until its next deadline, not by polling.

        While callers wait (or waited within READER_STANDBY_S) and nothing is due without them, the reader
        stands by and the callers read (`_wait`); it takes the channel back when they are gone."""
        channel = self._channel
        assert channel is not None
        cond = self._cond
        try:
            while not self._stop.is_set():
                with cond:
                    if self._stand_by():
                        continue
                    until, now = self._take_read()
                if not self._read_and_feed(channel, until - now):
                    return
        finally:
            with cond:
                self._reader_running = False
                cond.notify_all()  # a caller waiting on a job sees that no one will finish it

    def _stand_by(self) -> bool:
        """(lock held, reader thread) Wait aside while a caller reads, or while callers waited within
        READER_STANDBY_S and nothing is due without them (their next batch reads its own replies); True if it
        waited. Lines in flight that no caller reads for are the reader's."""
        if self._reading:
            self._park.wait(READER_STANDBY_S)
            return True
        quiet_s = time.monotonic() - self._callers_seen_s
        if quiet_s < READER_STANDBY_S and not self._draining and self._protocol.next_deadline() is None:
            self._park.wait(READER_STANDBY_S - quiet_s)
            return True
        return False

    def _take_read(self) -> tuple[float, float]:
        """(lock held) Take the read right; (until, now): the read ends at the next deadline, and no later than
        min_timeout_s (a line a caller writes has a deadline at least that far ahead, so it wakes in time)."""
        self._reading = True
        now = self.clock()
        deadline = self._protocol.next_deadline()
        idle_until = now + self.config.min_timeout_s
        until = idle_until if deadline is None or deadline > idle_until else deadline
        self._sleeping_until, self._asleep = until, True
        return until, now

    def _read_and_feed(self, channel: Channel, timeout_s: float) -> bool:
        """(lock not held, read right held) One read, fed to the protocol; gives the read right back. False when
        the port failed (the protocol is told, unless the driver is closing)."""
        cond, protocol = self._cond, self._protocol
        try:
            data = channel.read(timeout_s if timeout_s > 0.0 else 0.0)
        except BaseException as exc:  # SerialException, OSError: the port is gone; KeyboardInterrupt: a caller's
            with cond:
                self._reading = self._asleep = False
                if isinstance(exc, Exception) and not self._stop.is_set():
                    protocol.port_failed(f"read failed: {exc}")
                cond.notify_all()
                self._park.notify()
            if not isinstance(exc, Exception):
                raise
            return False
        with cond:
            self._reading = self._asleep = False  # awake: the next read starts from the next deadline
            try:
                self.reader_wakeups += 1
                if data:
                    self._log("<", data)
                    protocol.receive(data, self.clock())
                else:
                    protocol.tick(self.clock())
                self._flush()
            finally:
                if self._stop.is_set() or self._should_wake():
                    cond.notify_all()
        return True

    def _should_wake(self) -> bool:
        """Whether a blocked caller has something to see (called with the lock held)."""
        if self._protocol.failure is not None:
            return True
        if self._draining and self._protocol.drained:
            return True
        if self._protocol.has_events:
            self._collect()
            if any(job in self._results for job in self._awaited):
                return True
        if self._progress_waiters and self.clock() - self._progress_at >= 0.1:
            self._progress_at = self.clock()
            return True
        return False

    def _wake_reader_for(self) -> None:
        """After new work from a caller's thread (lock held): wake the reader if it sleeps past the new deadline."""
        if not self._asleep or self._channel is None:
            return
        deadline, until = self._protocol.next_deadline(), self._sleeping_until
        if deadline is not None and (until is None or deadline < until):
            self._wake_reading()

    def _wake_reading(self) -> None:
        """(lock held) End the read in progress now, whoever makes it: a caller blocked in a read sees a failed
        session or a job taken back at once, not at its read's deadline."""
        if self._asleep and self._channel is not None:
            self._asleep = False  # one wake is enough
            self._channel.wake()

    def _flush(self) -> None:
        """Write what the protocol asks for, in one write (called with the lock held).

        Several lines are due at once when lines are pipelined or replayed after a `Resend:`: one
        write (and one wire-log entry) for them all lets the printer read them as one burst."""
        pending = self._protocol.data_to_send()
        if not pending:
            return
        data = pending[0] if len(pending) == 1 else b"".join(pending)
        if not self._log(">", data):
            return
        try:
            channel = self._channel
            if channel is None:
                raise OSError("the port is not open")
            channel.write(data, self.config.write_timeout_s)
        except Exception as exc:  # noqa: BLE001 - any port failure is a dead port
            self._protocol.port_failed(f"write failed: {exc}")
            self._protocol.data_to_send()

    def _log(self, direction: str, data: bytes) -> bool:
        """Append to the wire log; a failing log ends the session as such, not as a dead port."""
        if self._wire is None:
            return True
        try:
            self._wire.write(direction, data)
            return True
        except (OSError, ValueError) as exc:
            n, cmd = self._protocol.last_acked
            where = f"{self._wire.path}: {exc}"
            self._protocol.fail(E.WireLogFailed(where, last_line=n, last_command=cmd, port=self.port_name))
            self._protocol.data_to_send()
            return False

    def _collect(self) -> None:
        """Take the protocol's events (lock held); the first event of a job is how it ended."""
        for event in self._protocol.events():
            self._results.setdefault(event.job, event)

    def _submit(self, jobs: list[Job]) -> None:
        with self._cond:
            if self._reader is None:
                raise E.PortDead("not connected: call connect() first", port=self.port_name)
            self._protocol.submit(jobs, self.clock())
            self._flush()
            self._wake_reader_for()

    def _wait(self, job: Job, progress: Callable[[], None] | None = None) -> Acknowledged:
        """Until the protocol ends job (it has a deadline for every line it sends); its Acknowledged event,
        or its Failed event's error raised. The caller reads its replies itself while no one else reads."""
        cond, channel = self._cond, self._channel
        with cond:
            self._awaited.append(job)
            self._progress_waiters += progress is not None
            self._callers_seen_s = time.monotonic()
        try:
            while True:
                with cond:
                    self._collect()
                    if job in self._results:
                        break
                    if not self._reader_running:
                        n, cmd = self._protocol.last_acked
                        error = E.PortDead(
                            "the reader thread stopped", last_line=n, last_command=cmd, port=self.port_name
                        )
                        self._protocol.fail(error)
                        self._collect()
                        self._results.setdefault(job, Failed(job, error))
                        break
                    reading = not self._reading and channel is not None and not self._stop.is_set()
                    if reading:
                        until, now = self._take_read()
                    else:
                        # no timeout: whoever reads notifies when this job finishes, the session fails, progress
                        # is due (0.1 s on the driver's clock) or the reader ends; every line has a deadline
                        cond.wait()
                if reading:
                    assert channel is not None
                    self.caller_reads += 1
                    self._read_and_feed(channel, until - now)
                if progress is not None:
                    progress()
        finally:
            with cond:
                self._awaited.remove(job)
                self._progress_waiters -= progress is not None
                self._callers_seen_s = time.monotonic()
                if self._awaited:
                    if not self._reading:
                        cond.notify_all()  # callers still wait and no one reads: one of them takes the read
                elif self._protocol.next_deadline() is not None or self._draining:
                    self._park.notify()  # work left with no caller to read for it: the reader takes over now
        result = self._results[job]
        if isinstance(result, Failed):
            raise result.error
        return result

    # ---- public API ---------------------------------------------------------------------------

    def send(self, command: str, *, strict: bool = True) -> list[str]:
        """Send one command and wait for its `ok`; the reply lines before the `ok` (M114 text, echoes),
        then any data carried on the `ok` line itself (`ok T:25.00 /0.00` gives "T:25.00 /0.00").

        strict: raise CommandRejected when Marlin refuses it (`Unknown command`, `Home XYZ First`).
        Once the printer has sent an unexplained `ok`, each command is confirmed by a probe's echo.
        """
        command = clean_command(command)
        job = Job(command)
        jobs = [job]
        if self._protocol.confirming:
            jobs.append(Job("", barrier=True))
        self._submit(jobs)
        try:
            self._wait(jobs[-1])
            result = self._wait(job)  # ended already: the barrier (if any) came after it
        finally:
            with self._cond:
                for one in jobs:
                    self._results.pop(one, None)
        if strict and result.rejected:
            raise E.CommandRejected(
                f"{result.rejected!r} in answer to N{result.line} {command!r}",
                last_line=result.line,
                last_command=command,
                port=self.port_name,
            )
        return list(result.replies)

    def send_lines(
        self, lines: Iterable[str], progress: Callable[[int, int], None] | None = None, *, source: str = "<lines>"
    ) -> int:
        """Send a program in order, exactly once each; returns the number of commands sent.

        Comments and blank lines are dropped; every line is parsed first, so a syntax error
        raises before anything is sent. progress(done, total) is called as lines are acknowledged.
        A refused command stops the batch (CommandRejected) with the rest unsent. With
        config.confirm_batches (or once the printer was seen duplicating an `ok`) the batch ends with
        a probe (`M118 E1 neatskin-probe N`) whose echo proves that every line ran, so a duplicated
        `ok` cannot make this return before the printer ran the batch.
        """
        program = self._commands.parse_batch(lines, source)  # the protocol sizes deadlines from these
        if not program:
            return 0
        batch = object()
        jobs = [Job(command, line, batch) for command, line in program]
        with self._cond:  # the previous batch's results are no longer asked for
            for old in self._batch:
                self._results.pop(old, None)
        self._batch = jobs
        last = jobs[-1]
        if self._protocol.confirming:
            last = Job("", batch=batch, barrier=True)
        self._submit(jobs if last is jobs[-1] else [*jobs, last])

        shown = [0.0]

        def report() -> None:
            now = self.clock()
            if progress is not None and now - shown[0] >= 0.1:
                shown[0] = now
                progress(self.batch_acknowledged(), len(jobs))

        try:
            self._wait(last, report)
        finally:
            if last is not jobs[-1]:
                with self._cond:
                    self._results.pop(last, None)
        for job in jobs:
            result = self._results.get(job)
            if isinstance(result, Acknowledged) and result.rejected:
                raise E.CommandRejected(
                    f"{result.rejected!r} in answer to N{result.line} {job.command!r}",
                    last_line=result.line,
                    last_command=job.command,
                    port=self.port_name,
                )
        if progress is not None:
            progress(len(jobs), len(jobs))
        return len(jobs)

    def batch_acknowledged(self) -> int:
        """How many commands of the latest send_lines batch the printer acknowledged (a prefix, in order)."""
        with self._cond:
            self._collect()
            done = 0
            for job in self._batch:
                if not isinstance(self._results.get(job), Acknowledged):
                    break
                done += 1
            return done

    def stop_after_line_in_flight(self, timeout_s: float | None = None) -> int:
        """Take back every command not yet written, wait for the line in flight; the number acknowledged.

        For Ctrl-C: nothing new goes out; the session stays usable (a lift may follow)."""
        with self._cond:
            n, cmd = self._protocol.last_acked
            self._protocol.cancel_queued(
                E.Interrupted("taken back before sending", last_line=n, last_command=cmd, port=self.port_name)
            )
            self._cond.notify_all()  # a caller blocked on a job taken back sees it now
            # the read in progress ends now, and the next one starts from the drain's deadline: the time limit is the
            # protocol's, on the driver's clock; whoever reads wakes for it and tells us
            self._wake_reading()
            self._protocol.drain(self.clock(), timeout_s if timeout_s is not None else self.config.max_busy_s)
            self._draining += 1
            self._park.notify()  # the reader reads for a drain (the caller waits on the condition)
            try:
                while not self._protocol.drained and self._reader_running:
                    self._cond.wait()
            finally:
                self._draining -= 1
        return self.batch_acknowledged()

    def sync(self) -> None:
        """M400: return when every queued move has finished."""
        self.send("M400")

    def position(self) -> Position:
        """M114, parsed (`X:.. Y:.. Z:..` on its own line or on the `ok`); BadReply if no position came."""
        replies = self.send("M114")
        try:
            return parse_m114(replies)
        except ValueError as exc:
            n, cmd = self._protocol.last_acked
            raise E.BadReply(str(exc), last_line=n, last_command=cmd, port=self.port_name) from exc

    def endstops(self) -> dict[str, bool]:
        """M119, parsed: {"x_min": False, "z_min": True, ...} (True = triggered); BadReply if none came."""
        replies = self.send("M119")
        try:
            return parse_m119(replies)
        except ValueError as exc:
            n, cmd = self._protocol.last_acked
            raise E.BadReply(str(exc), last_line=n, last_command=cmd, port=self.port_name) from exc

    def emergency_stop(self) -> None:
        """Send M112 at once, ahead of anything queued; the session ends (EmergencyStopped)."""
        with self._cond:
            self._protocol.emergency_stop()
            self._flush()
            self._cond.notify_all()
            self._wake_reading()

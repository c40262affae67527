"""The live link under MarlinDriver: the reader thread, the read right a waiting caller takes, the writes, the wire log.

`Link` is the transport around one sans-IO `LineProtocol` (linestate.py): it reads the port's
`Channel` (transport.py) and feeds the protocol what it reads and the time, writes what the
protocol asks for (both ways to the wire log), and lets callers block until their jobs end. One
thread at a time holds the read right (bytes are handled in order): the reader thread, or a caller
blocked on its job, who then reads its own replies. Every wait here ends when the protocol finishes
or fails the job, and the protocol has a deadline for every line. What a command is and how a
refusal is reported is the command API's (driver.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from os import PathLike

from neatskin.marlin import errors as E
from neatskin.marlin.jobs import Acknowledged, DriverConfig, Event, Failed, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.marlin.transport import Channel, Clock
from neatskin.marlin.wirelog import WireLog

READER_STANDBY_S = 0.25  # the reader stands by this long after a caller waited (wall seconds: thread scheduling)


class Link:
    """A driver's I/O around its protocol: start and stop a session's reader, submit jobs, wait for them."""

    def __init__(self, protocol: LineProtocol, config: DriverConfig, clock: Clock, port_name: str) -> None:
        self.config = config
        self.clock = clock
        self.port_name = port_name
        self._protocol = protocol
        self._wire: WireLog | None = None
        lock = threading.RLock()
        self._cond = threading.Condition(lock)
        self._reader: threading.Thread | None = None
        self._channel: Channel | None = None
        self._stop = threading.Event()
        # what callers block on: the reader wakes them only when one of these finished (or the session
        # failed, or a drain ended), not for every `ok` of a batch: a waiter woken per line competes with
        # the reader for the lock and the GIL on the hot path
        self._awaited: list[Job] = []
        self._results: dict[Job, Event] = {}  # how each job ended, from the protocol's events, until read
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

    @property
    def running(self) -> bool:
        """Whether a session's reader was started and not stopped since (the session may have failed)."""
        return self._reader is not None

    # ---- a session's start and end ------------------------------------------------------------

    def open_wire_log(self, path: str | PathLike[str] | None) -> None:
        """Open the wire log at path (None: none), unless one is open; WireLogFailed if it cannot be."""
        if path is not None and self._wire is None:
            try:
                self._wire = WireLog(path, clock=self.clock)
            except OSError as exc:
                raise E.WireLogFailed(f"{path}: {exc}", port=self.port_name) from exc

    def close_wire_log(self) -> None:
        if self._wire is not None:
            self._wire.close()
            self._wire = None

    def start(self, channel: Channel, boot_timeout_s: float | None) -> None:
        """Begin a session on channel: the handshake goes out, the reader starts, and this returns once the
        printer acknowledged the handshake (or raises how it failed)."""
        self._channel = channel
        with self._cond:
            hello = self._protocol.start_session(self.clock(), boot_timeout_s)
            self._flush()
        self._stop.clear()
        self._reader_running = True
        self._reader = threading.Thread(target=self._run, name=f"marlin-reader {self.port_name}", daemon=True)
        self._reader.start()
        self.wait(hello)
        self._results.pop(hello, None)

    def stop(self) -> None:
        """End the session's reader (a caller in a read ends it too) and fail the session as closed: every waiting
        caller sees PortDead. The port itself stays the driver's."""
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

    # ---- the reader thread, the read right and the writes ---------------------------------------

    def _run(self) -> None:
        """Read, feed the protocol, write what it asks for; sleep until its next deadline, not by polling.

        While callers wait (or waited within READER_STANDBY_S) and nothing is due without them, the reader
        stands by and the callers read (`wait`); it takes the channel back when they are gone."""
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

    def submit(self, jobs: list[Job]) -> None:
        """Hand jobs to the protocol and write what goes out now; PortDead before connect."""
        with self._cond:
            if self._reader is None:
                raise E.PortDead("not connected: call connect() first", port=self.port_name)
            self._protocol.submit(jobs, self.clock())
            self._flush()
            self._wake_reader_for()

    def wait(self, job: Job, progress: Callable[[], None] | None = None) -> Acknowledged:
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

    # ---- what callers ask of the session ------------------------------------------------------

    def result(self, job: Job) -> Event | None:
        """How job ended, if it did and was not forgotten."""
        return self._results.get(job)

    def forget(self, jobs: Iterable[Job]) -> None:
        """Drop the results of jobs no one will ask about again."""
        with self._cond:
            for job in jobs:
                self._results.pop(job, None)

    def acknowledged_prefix(self, jobs: Iterable[Job]) -> int:
        """How many of jobs, from the first, the printer acknowledged."""
        with self._cond:
            self._collect()
            done = 0
            for job in jobs:
                if not isinstance(self._results.get(job), Acknowledged):
                    break
                done += 1
            return done

    def take_back_and_drain(self, timeout_s: float) -> None:
        """Take back every job not yet written (they fail with Interrupted), then wait for the lines in flight
        within timeout_s (the protocol's drain, on the driver's clock)."""
        with self._cond:
            n, cmd = self._protocol.last_acked
            self._protocol.cancel_queued(
                E.Interrupted("taken back before sending", last_line=n, last_command=cmd, port=self.port_name)
            )
            self._cond.notify_all()  # a caller blocked on a job taken back sees it now
            # the read in progress ends now, and the next one starts from the drain's deadline: the time limit is the
            # protocol's, on the driver's clock; whoever reads wakes for it and tells us
            self._wake_reading()
            self._protocol.drain(self.clock(), timeout_s)
            self._draining += 1
            self._park.notify()  # the reader reads for a drain (the caller waits on the condition)
            try:
                while not self._protocol.drained and self._reader_running:
                    self._cond.wait()
            finally:
                self._draining -= 1

    def emergency_stop(self) -> None:
        """M112 out at once, ahead of anything queued; every waiting caller sees the session end."""
        with self._cond:
            self._protocol.emergency_stop()
            self._flush()
            self._cond.notify_all()
            self._wake_reading()

"""The Marlin line protocol as a sans-IO state machine: bytes and time in, bytes to write and finished jobs out.

`LineProtocol` owns every piece of protocol state (line numbers, the lines in flight, resends,
deadlines, lost-`ok` probes, the connect handshake) and touches no port, thread or clock: the
caller feeds it what the printer said (`receive(data, now)`), the passing of time (`tick(now)`)
and work (`start_session`, `submit`), and takes the bytes to write (`data_to_send()`) and how
jobs ended (`events()`: Acknowledged or Failed, as h11 returns events; a Job is never mutated). Every wait it keeps has a
deadline and every retry a cap, so a hostile peer ends in one MarlinError, never a loop.
The transport around it (driver.py) owns the port, the reader thread and the clock.
One module over the usual size on purpose: every transition reads and writes the same session
state, and a reader should see the whole machine in one place (values live in jobs.py).
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field

from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import errors as E
from neatskin.marlin.deadlines import MotionTracker
from neatskin.marlin.jobs import Acknowledged, DriverConfig, Event, Failed, Job
from neatskin.marlin.replies import PROBE_TAG, Kind, Reply, classify, frame
from neatskin.marlin.resends import ResendState

log = logging.getLogger(__name__)


@dataclass(eq=False)
class _Line:
    n: int
    command: str
    data: bytes
    job: Job | None
    deadline: float
    hard_deadline: float
    probe: bool = False
    m110: bool = False
    echoed: bool = False
    replies: list[str] = field(default_factory=list)  # what the printer said for it before its ok
    rejected: str | None = None
    bare_oks: int = 0  # oks that came while this probe had not echoed
    superseded: bool = False  # an M118 probe the firmware never echoed: an M114 probe went out after it
    released: bool = False  # its caller was told it is acknowledged


_SYNCHRONISING = frozenset({"G28", "G4", "M400", "G29"})
_BOOT_SETTLE_S = 0.05  # after `start`, let the banner finish before the handshake
_MAX_LINE_BYTES = 4096  # a reply line longer than this is garbage


class LineProtocol:
    """Marlin's host protocol, one session at a time; see the module docstring for the contract."""

    def __init__(
        self,
        config: DriverConfig = DriverConfig(),
        profile: PrinterProfile | None = None,
        port_name: str = "<port>",
        *,
        rx_buffer_size: int | None = None,
    ) -> None:
        self.config = config
        self.profile = profile
        self.port_name = port_name
        # the firmware's RX_BUFFER_SIZE: given, else the profile's, else Marlin's stock 128; bytes in flight
        # stay below it (one byte short, as Marlin's ring keeps one free)
        size = rx_buffer_size or (profile.rx_buffer_size if profile is not None else config.rx_buffer_bytes + 1)
        if size < 2:
            raise ValueError(f"rx_buffer_size must be >= 2 bytes, got {size}")
        self.rx_budget_bytes = size - 1
        self._outbox: list[bytes] = []
        self._events: list[Event] = []
        self.stats: collections.Counter[str] = collections.Counter()
        self.reset(0.0)
        self.failure: E.MarlinError | None = E.PortDead("not connected: call connect() first", port=port_name)

    def reset(self, now: float) -> None:
        """Forget the session: counters, queues, the commanded position, the learned dialect."""
        self._next_n = 0
        self._rx = b""
        self._queue: collections.deque[Job] = collections.deque()
        self._inflight: list[_Line] = []
        self.failure = None
        self.session = False
        self.booted = False
        self._phase = "idle"  # idle -> booting -> handshake -> session
        self._boot_seen_s: float | None = None
        self._boot_deadline = now
        self._connect_deadline = now
        self._connect_attempts = 0
        self._starts = 0
        self._hello: Job | None = None
        self._hello_ended = False
        self.last_acked: tuple[int | None, str | None] = (None, None)
        self.acked_jobs = 0
        self._history: dict[int, _Line] = {}  # recently acknowledged lines, for a firmware that never took them
        self._resend = ResendState(self.config.ok_after_resend)
        self._advanced_ok_seen = False
        self._queue_free: int | None = None  # B of the latest `ok N.. P.. B..`: free slots of Marlin's command queue
        self._probe_fallback = False  # the firmware answered an M118 probe with a bare ok: probe with M114 instead
        self._probes_in_stall = 0
        self._drain_deadline: float | None = None
        self.drain_expired = False
        self.motion = MotionTracker(self.profile, self.config.homing_time_s, self.config.default_feed_mm_s)
        self._motion_end = 0.0
        # when each of the latest moves ends (host model): a move's ok waits at most for a planner slot
        slots = (self.profile.planner_buffer_size if self.profile is not None else 16) - 1
        self._move_ends: collections.deque[float] = collections.deque(maxlen=max(slots, 1))
        self.unsolicited: collections.deque[str] = collections.deque(maxlen=200)
        self.actions: list[str] = []
        self.stats = collections.Counter()

    # ---- inputs -----------------------------------------------------------------------------

    def start_session(self, now: float, boot_timeout_s: float | None = None) -> Job:
        """Begin a session: wait for `start` (or boot_timeout_s), then `M110 N0`; the returned job is the handshake."""
        self.reset(now)
        wait_s = self.config.boot_timeout_s if boot_timeout_s is None else boot_timeout_s
        self._phase = "booting"
        self._boot_deadline = now + wait_s
        self._connect_deadline = now + wait_s + self.config.connect_timeout_s
        self._hello = Job("M110 N0")
        if wait_s <= 0:
            self._say_hello(now)
        return self._hello

    def submit(self, jobs: Iterable[Job], now: float) -> None:
        """Queue jobs in order; they go out as the line frees. Raises the session's failure, if any."""
        if self.failure is not None:
            raise self.failure
        self._queue.extend(jobs)
        self._pump(now)

    def receive(self, data: bytes, now: float) -> None:
        """What the printer said: complete lines are handled at once, a partial line waits for its end;
        then `tick(now)`, so the next line goes out only after the whole chunk was read."""
        self._rx += data
        *complete, self._rx = self._rx.split(b"\n")
        for raw in complete:
            if self.failure is not None:
                break
            self._on_line(raw.decode("ascii", "replace").strip(), now)
        if len(self._rx) > _MAX_LINE_BYTES:  # garbage without a newline: keep the tail only
            self.stats["garbage_bytes"] += len(self._rx) - _MAX_LINE_BYTES
            self._rx = self._rx[-_MAX_LINE_BYTES:]
        self.tick(now)

    def next_deadline(self) -> float | None:
        """The earliest time at which tick() has something to do (None: nothing until the printer says
        something or new work comes): a transport sleeps until it instead of polling."""
        if self.failure is not None:
            return None
        if self._phase == "session" and self._resend.pending is None and self._drain_deadline is None:
            return self._inflight[0].deadline if self._inflight else None  # the common case, per read
        if self._phase == "booting":
            settle = None if self._boot_seen_s is None else self._boot_seen_s + _BOOT_SETTLE_S
            return self._boot_deadline if settle is None else min(settle, self._boot_deadline)
        times: list[float] = []
        if self._phase == "handshake":
            times.append(self._connect_deadline)
        if self._resend.pending is not None:
            times.append(self._resend.due)
        elif self._inflight:
            times.append(self._inflight[0].deadline)
        if self._drain_deadline is not None and not self.drain_expired:
            times.append(self._drain_deadline)
        return min(times) if times else None

    def drain(self, now: float, timeout_s: float) -> None:
        """Wait for the lines in flight no longer than timeout_s: `drained` turns true when none is left, the
        session failed, or the time is up (drain_expired). Queued jobs are taken back by cancel_queued."""
        self._drain_deadline = now + timeout_s
        self.drain_expired = False

    @property
    def drained(self) -> bool:
        return not self._inflight or self.failure is not None or self.drain_expired

    def tick(self, now: float) -> None:
        """Let time pass: replay requested lines, probe overdue ones, send queued ones, fail what is too late."""
        if self._drain_deadline is not None and now >= self._drain_deadline:
            self.drain_expired = True
            self._drain_deadline = None
        if self.failure is not None:
            return
        if self._phase == "booting":
            settled = self._boot_seen_s is not None and now >= self._boot_seen_s + _BOOT_SETTLE_S
            if settled or now >= self._boot_deadline:
                self._say_hello(now)
            return
        if self._phase == "handshake" and now >= self._connect_deadline:
            self._fail_here(
                E.ConnectFailed,
                f"no handshake within {self.config.connect_timeout_s:g} s "
                f"({self._connect_attempts} M110 sent, {self._starts} `start` seen)",
            )
            return
        if self._resend.pending is not None and now >= self._resend.due:
            self._replay(now)
        if not self._inflight:
            self._pump(now)
            return
        head = self._inflight[0]
        if now < head.deadline or self._resend.pending is not None:
            return
        self._overdue(head, now)

    def cancel_queued(self, error: E.MarlinError) -> int:
        """Take back every job not yet written (they finish with `error`); lines in flight go on."""
        jobs = list(self._queue)
        self._queue.clear()
        self._events.extend(Failed(job, error) for job in jobs)
        return len(jobs)

    def emergency_stop(self) -> None:
        """M112 ahead of everything; the session ends."""
        self._outbox.append(b"M112\n")
        self._fail_here(E.EmergencyStopped, "M112 sent on request")

    def port_failed(self, detail: str) -> None:
        self._fail_here(E.PortDead, detail)

    # ---- outputs ----------------------------------------------------------------------------

    @property
    def has_events(self) -> bool:
        return bool(self._events)

    def events(self) -> list[Event]:
        """How jobs ended since the last call, in order (each job ends once: Acknowledged or Failed)."""
        out, self._events = self._events, []
        return out

    def data_to_send(self) -> list[bytes]:
        """The writes due, in order (one entry per line); the caller writes them and calls again later."""
        out, self._outbox = self._outbox, []
        return out

    @property
    def confirming(self) -> bool:
        """Whether batches end with a confirming probe now (config.confirm_batches, or oks seen duplicated)."""
        mode = self.config.confirm_batches
        return mode is True or (mode is None and self.stats["stray_oks"] > 0)

    @property
    def in_flight(self) -> int:
        return len(self._inflight)

    @property
    def queued(self) -> int:
        return len(self._queue)

    # ---- the handshake ----------------------------------------------------------------------

    def _say_hello(self, now: float) -> None:
        assert self._hello is not None
        self._phase = "handshake"
        self._connect_attempts = 1
        self._send_line(self._hello, m110=True, now=now)

    def _hello_again(self, now: float, why: str) -> None:
        """M110 is idempotent: say it again, within the connect cap."""
        self._connect_attempts += 1
        if self._connect_attempts > self.config.connect_attempts:
            self._fail_here(
                E.ConnectFailed,
                f"{why}; M110 N0 was sent {self.config.connect_attempts} times "
                f"and the printer never acknowledged it ({self._starts} `start` seen)",
            )
            return
        self._resend.pending = self._inflight[0].n
        self._resend.due = now + _BOOT_SETTLE_S
        self._resend.ok_seen = False

    # ---- writing ----------------------------------------------------------------------------

    def _deadline(self, command: str | GcodeLine, now: float) -> float:
        own_s, waits = self.motion.line_time_s(command)
        own_s *= self.config.motion_time_scale
        queued_end = max(now, self._motion_end)
        self._motion_end = queued_end + own_s
        if waits:  # it runs after the queued motion (M400, G4, G28, and conservatively anything not a move)
            return self._motion_end + self.config.min_timeout_s
        # a move is acknowledged once it has a planner slot: at the latest when the move `slots` back ends
        ends = self._move_ends
        slot_free = ends[0] if len(ends) == ends.maxlen else now
        ends.append(self._motion_end)
        return max(now, slot_free) + own_s + self.config.min_timeout_s

    def _send_line(self, job: Job | None, *, now: float, probe: bool = False, m110: bool = False) -> _Line:
        n = self._next_n
        self._next_n += 1
        if probe:
            command = "M114" if self._probe_fallback else f"M118 E1 {PROBE_TAG} {n}"
        else:
            command = job.command if job is not None else ""
        if probe or m110:
            deadline = max(now, self._motion_end) + self.config.min_timeout_s
        else:
            assert job is not None
            deadline = self._deadline(job.parsed or command, now)
        line = _Line(n, command, frame(command, n), job, deadline, deadline + self.config.max_busy_s, probe, m110)
        self._inflight.append(line)
        self.stats["lines_sent"] += 1
        stats = self.stats
        if len(self._inflight) == 1:  # the common case, kept cheap: it runs once per line
            live = len(line.data)
        else:
            stats["max_in_flight"] = max(stats["max_in_flight"], len(self._inflight))
            live = sum(len(other.data) for other in self._inflight if other.deadline > now or other is line)
        if live > stats["max_bytes_in_flight"]:
            stats["max_bytes_in_flight"] = live
        if not stats["max_in_flight"]:
            stats["max_in_flight"] = 1
        self._outbox.append(line.data)
        return line

    def _pump(self, now: float) -> None:
        if self._phase != "session":
            return
        while self._queue and self.failure is None and self._resend.pending is None and self._room_for(self._queue[0]):
            job = self._queue.popleft()
            self._send_line(job, now=now, probe=job.barrier)

    def _room_for(self, job: Job) -> bool:
        """One line in flight; more only once the firmware's `ok N..` names its lines, and then within the
        firmware's own accounting: never more lines than the free queue slots its latest `B` reported,
        one slot short of max_in_flight (kept for a lost-ok probe), bytes within its RX buffer, and never
        past a probe or an M110."""
        if not self._inflight:
            return True
        if self.config.max_in_flight <= 1 or not self._advanced_ok_seen or job.barrier:
            return False
        lines = len(self._inflight) + 1
        if lines > self.config.max_in_flight - 1 or any(line.probe or line.m110 for line in self._inflight):
            return False
        if self._queue_free is not None and lines > max(1, self._queue_free):
            return False
        in_flight = sum(len(line.data) for line in self._inflight)
        return in_flight + len(job.command) + 16 <= self.rx_budget_bytes

    # ---- reading ----------------------------------------------------------------------------

    def _on_line(self, text: str, now: float) -> None:
        if not text:
            return
        reply = classify(text)
        kind = reply.kind
        head = self._inflight[0] if self._inflight else None
        if kind is Kind.OK:
            self._on_ok(reply, now)
        elif kind is Kind.RESEND:
            assert reply.number is not None
            self._on_resend(reply.number, now)
        elif kind is Kind.COMM_ERROR:
            self._resend.comm_errors += 1
            self._resend.fw_last_line = reply.number
            self.stats["comm_errors"] += 1
        elif kind in (Kind.HALTED, Kind.STOPPED):
            self._fail_here(E.PrinterHalted, f"the printer said {text!r}")
        elif kind is Kind.START:
            self._on_start(now)
        elif kind is Kind.BUSY:
            self.stats["busy"] += 1
            for line in self._inflight:
                line.deadline = min(max(line.deadline, now + self.config.busy_extension_s), line.hard_deadline)
        elif kind is Kind.PROBE_ECHO:
            assert reply.number is not None
            self._on_probe_echo(reply.number, now)
        elif kind is Kind.WAIT:
            pass
        elif kind is Kind.DATA and self._probe_fallback and self._position_for_probe(text, now):
            pass
        else:
            if kind is Kind.ACTION:
                self.actions.append(text)
            if head is not None and head.job is not None and not head.probe:
                head.replies.append(text)
                if kind in (Kind.UNKNOWN_COMMAND, Kind.REJECTED):
                    head.rejected = text
            else:
                self.unsolicited.append(text)

    def _on_start(self, now: float) -> None:
        self._starts += 1
        self.booted = True
        if self.session:
            self._fail_here(E.PrinterReset, "the printer sent 'start' (it rebooted)")
        elif self._phase == "booting":
            if self._starts > self.config.connect_attempts:
                self._fail_here(E.ConnectFailed, f"the printer sent 'start' {self._starts} times (a boot loop)")
            elif self._boot_seen_s is None:
                self._boot_seen_s = now
        elif self._phase == "handshake" and self._inflight and self._inflight[0].m110:
            if self._resend.pending is None:
                self._hello_again(now, "the printer rebooted under the handshake (`start`)")
                self._resend.ok_seen = True  # not a `Resend:`: an ok now teaches nothing about the dialect
            else:
                self._connect_attempts += 1  # a `start` flood: every one counts against the cap
                if self._connect_attempts > self.config.connect_attempts:
                    self._fail_here(E.ConnectFailed, f"the printer sent 'start' {self._starts} times (a boot loop)")

    def _on_ok(self, reply: Reply, now: float) -> None:
        pending = self._resend.pending
        if pending is not None and (not self._inflight or self._inflight[0].n >= pending):
            # a line at or after the rejected one cannot be acknowledged before it is replayed:
            # this is the `ok` that Marlin 1.x, Repetier and OctoPrint send after `Resend:` (or a duplicate)
            self.stats["oks_swallowed"] += 1
            if not self._resend.ok_seen:
                self._resend.ok_seen = True
                if self._resend.ok_after is None:
                    log.debug("learned: this firmware sends `ok` after `Resend:`")
                    self._resend.ok_after = True
                if self._resend.ok_after:
                    self._resend.due = now  # replay now: its `ok` can no longer be mistaken for the replay's
            return
        if not self._inflight:
            self.stats["stray_oks"] += 1
            return
        head = self._inflight[0]
        if reply.buffer_free is not None:
            self._queue_free = reply.buffer_free
        if reply.number is not None:  # ADVANCED_OK names the line
            self._advanced_ok_seen = True
            if reply.number < head.n:
                self.stats["stale_oks"] += 1
                return
            while self._inflight and self._inflight[0].n <= reply.number:
                self._retire(self._inflight[0], now)
        elif self._probe_fallback and reply.text[2:].lstrip(" :").startswith("X:") and self._ok_answers_probe(now):
            return  # `ok X:.. Y:.. Z:..` (OctoPrint's M114 form) answered the fallback probe
        elif head.probe and not head.echoed:
            # the firmware echoes a probe before its ok: this ok is a duplicate of an earlier one, or the
            # firmware does not echo M118 (then the probe falls back to M114 when it is overdue)
            head.bare_oks += 1
            self.stats["stray_oks"] += 1
            return
        else:
            payload = reply.text[2:].lstrip(" :")
            if payload and reply.planner_free is None and head.job is not None and not head.probe:
                head.replies.append(payload)  # data carried on the ok line (`ok T:25.00 /0.00`)
            self._retire(head, now)
        # the next line goes out in tick(), after the whole chunk is read: a duplicated `ok` in the
        # same chunk then finds nothing in flight instead of acknowledging a line just sent

    def _retire(self, line: _Line, now: float) -> None:
        self._inflight.remove(line)
        self._probes_in_stall = 0
        self._resend.stale_streak = 0
        self._history[line.n] = line
        self._history.pop(line.n - 128, None)
        if line.released:  # acknowledged again after a rewind: its caller already went on
            return
        line.released = True
        self._resend.counts.pop(line.n, None)
        if not line.probe:
            self.last_acked = (line.n, line.command)
        if line.command.split(" ", 1)[0] in _SYNCHRONISING:  # its ok means the planner ran empty
            self._motion_end = min(self._motion_end, now)
            self._move_ends.clear()
        if line.m110:
            self._phase = "session"
            self.session = True
        job = line.job
        if job is None:
            return
        self.acked_jobs += 1
        if job is self._hello:
            self._hello_ended = True
        self._events.append(Acknowledged(job, line.n, tuple(line.replies), line.rejected))
        if line.rejected and job.batch is not None:
            self._cancel_batch(line)

    def _cancel_batch(self, refused: _Line) -> None:
        job = refused.job
        assert job is not None
        rest = [j for j in self._queue if j.batch is job.batch]
        self._queue = collections.deque(j for j in self._queue if j.batch is not job.batch)
        for other in rest:
            error = E.CommandRejected(
                f"not sent: N{refused.n} {job.command!r} was refused ({refused.rejected!r})",
                last_line=refused.n,
                last_command=job.command,
                port=self.port_name,
            )
            self._events.append(Failed(other, error))

    # ---- resends ----------------------------------------------------------------------------

    def _resend_wait_s(self) -> float:
        """How long to wait for the dialect's `ok` after `Resend:` before replaying."""
        return self._resend.wait_s(self.config.resend_grace_s, self.config.min_timeout_s)

    def _on_resend(self, n: int, now: float) -> None:
        self.stats["resend_requests"] += 1
        if not self._inflight:
            self.stats["stale_resends"] += 1
            return
        head = self._inflight[0]
        if head.m110:
            if self._resend.pending is None:
                self._hello_again(now, f"the printer asked for line {n} under the handshake")
            return
        fresh = self._resend.fresh_error_for(n)
        if n > self._inflight[-1].n:  # it has every line in flight: nothing to replay
            self.stats["stale_resends"] += 1
            while fresh and self._inflight and self._inflight[0].probe:
                self._retire(self._inflight[0], now)  # a probe it took (its echo went missing) is done
            return
        if n < head.n:
            if fresh and all(m in self._history for m in range(n, head.n)):
                # the firmware says it never took lines we counted as acknowledged (a duplicated ok):
                # they are replayed under their own numbers, so nothing runs twice
                self.stats["rewinds"] += 1
                self._inflight[:0] = [self._history.pop(m) for m in range(n, head.n)]
            else:
                self.stats["stale_resends"] += 1
                self._resend.stale_streak += 1
                if self._resend.stale_streak > self.config.max_resends:
                    self._fail_here(E.ResendLoop, f"the printer keeps asking for N{n}, acknowledged before")
                return
        served_n, served_errors, served_at = self._resend.served
        if (
            n == served_n
            and self._resend.comm_errors == served_errors
            and now - served_at < self.config.duplicate_resend_s
        ):
            self.stats["duplicate_resends"] += 1
            return
        if self._resend.pending is not None and self._resend.pending <= n:
            self.stats["duplicate_resends"] += 1
            return
        self._resend.counts[n] += 1
        if self._resend.counts[n] > self.config.max_resends:
            self._fail_here(E.ResendLoop, f"line N{n} was asked for {self._resend.counts[n]} times")
            return
        self._resend.pending, self._resend.due, self._resend.ok_seen = n, now + self._resend_wait_s(), False
        self._resend.served = (n, self._resend.comm_errors, now)

    def _replay(self, now: float) -> None:
        n = self._resend.pending
        assert n is not None
        self._resend.pending = None
        if self._resend.ok_after is None and not self._resend.ok_seen:
            self._resend.without_ok += 1
            if self._resend.without_ok >= 3:
                log.debug("learned: this firmware sends no `ok` after `Resend:`")
                self._resend.ok_after = False
        for line in self._inflight:
            if line.n >= n or line.m110:
                self.stats["lines_resent"] += 1
                line.deadline = max(line.deadline, now + self.config.min_timeout_s)
                self._outbox.append(line.data)
        self._resend.served = (n, self._resend.comm_errors, now)

    # ---- lost oks -----------------------------------------------------------------------------

    def _on_probe_echo(self, k: int, now: float) -> None:
        probe = next((line for line in self._inflight if line.n == k and line.probe), None)
        if probe is None:
            self.stats["stale_probe_echoes"] += 1
            return
        before = [line for line in self._inflight if line.n < k]
        self.stats["oks_recovered"] += len(before)
        for line in before:
            self._retire(line, now)  # the firmware ran the probe, so it ran every line before it
        probe.echoed = True
        probe.deadline = now + self.config.min_timeout_s

    def _ok_answers_probe(self, now: float) -> bool:
        """A position carried on an `ok` answers the first M114 in flight: when that is the fallback probe,
        it ran every line before it (its echo and its ok at once)."""
        first = next((line for line in self._inflight if line.command == "M114" and not line.echoed), None)
        if first is None or not first.probe:
            return False
        self._on_probe_echo(first.n, now)
        self._retire(first, now)
        return True

    def _position_for_probe(self, text: str, now: float) -> bool:
        """An M114 reply that answers the fallback probe (the first M114 in flight not yet answered is it)."""
        if not text.startswith("X:") or " Count " not in text:
            return False
        first = next((line for line in self._inflight if line.command == "M114" and not line.echoed), None)
        if first is None:
            return False
        first.echoed = True  # a caller's own M114 takes its own reply; a probe's is its echo
        if not first.probe:
            return False
        first.echoed = False
        self._on_probe_echo(first.n, now)
        return True

    def _overdue(self, head: _Line, now: float) -> None:
        if head.probe and head.echoed:  # the probe ran; its own ok was lost
            self.stats["oks_recovered"] += 1
            self._retire(head, now)
            self._pump(now)
            return
        if head.m110:  # M110 is idempotent: say it again
            self._resend.counts[head.n] += 1
            if self._resend.counts[head.n] > self.config.probe_attempts:
                self._fail_here(
                    E.NoAnswer,
                    f"no answer to {head.command!r} within {self.config.min_timeout_s:g} s, "
                    f"{self.config.probe_attempts} times",
                )
                return
            head.deadline = now + self.config.min_timeout_s
            self._outbox.append(head.data)
            return
        if head.probe and not head.echoed and head.bare_oks and not self._probe_fallback:
            # the firmware acknowledged the M118 probe with a bare ok and never echoed it (a firmware
            # without M118's echo): from now on probe with M114, whose position reply it prints only
            # once it ran every line before it
            log.debug("the printer answers M118 with a bare ok: probing with M114")
            self._probe_fallback = True
            self.stats["probe_fallbacks"] += 1
            head.superseded = True
        if self._probes_in_stall >= self.config.probe_attempts:
            self._fail_here(
                E.NoAnswer, f"no ok for N{head.n} {head.command!r} and no answer to {self._probes_in_stall} probes"
            )
            return
        pending = next((line for line in self._inflight if line.probe and not line.superseded), None)
        if pending is None and not self._probe_fits(now):
            # the probe counts against the cap: wait until the lines still due leave room for it
            head.deadline = min(line.deadline for line in self._inflight if line.deadline > now)
            self.stats["probes_deferred"] += 1
            return
        self._probes_in_stall += 1
        self.stats["probes"] += 1
        if pending is not None:  # the probe itself went missing: say it again under its number
            pending.deadline = max(now, self._motion_end) + self.config.min_timeout_s
            self._outbox.append(pending.data)
            probe = pending
        else:
            probe = self._send_line(None, now=now, probe=True)
        for line in self._inflight:
            line.deadline = max(line.deadline, probe.deadline)

    def _probe_fits(self, now: float) -> bool:
        """Whether a new probe stays within max_in_flight lines and the RX budget. Lines past their
        deadline are out of the firmware's RX buffer (run, queued or lost), so they do not count."""
        live = [line for line in self._inflight if line.deadline > now]
        if not live:
            return True
        command = "M114" if self._probe_fallback else f"M118 E1 {PROBE_TAG} {self._next_n}"
        probe_bytes = len(frame(command, self._next_n))
        if len(live) + 1 > max(self.config.max_in_flight, 2):
            return False
        return sum(len(line.data) for line in live) + probe_bytes <= self.rx_budget_bytes

    # ---- failure ------------------------------------------------------------------------------

    def _fail_here(self, kind: type[E.MarlinError], detail: str) -> None:
        n, cmd = self.last_acked
        self.fail(kind(detail, last_line=n, last_command=cmd, port=self.port_name))

    def fail(self, error: E.MarlinError) -> None:
        """End the session with error (the first failure wins); every waiting job finishes with it."""
        if self.failure is None:
            self.failure = error
            log.debug("session failed: %s", error)
        jobs = [line.job for line in self._inflight if line.job is not None and not line.released]
        jobs += list(self._queue)
        if self._hello is not None and not self._hello_ended and self._hello not in jobs:
            jobs.append(self._hello)  # a handshake that failed before its M110 went out
        if self._hello is not None:
            self._hello_ended = True
        self._queue.clear()
        self._inflight.clear()
        self._resend.pending = None
        failure = self.failure
        self._events.extend(Failed(job, failure) for job in jobs)

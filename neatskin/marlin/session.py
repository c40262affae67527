"""One Marlin session's state and its primitives: the lines in flight, sending one, acknowledging one, failing.

`LineSession` holds everything a session knows (line numbers, the lines in flight and recently
acknowledged, the queue, the host's motion model, the learned dialect, the stats) and the steps
every transition is built from: frame, time and send a line (`_send_line`, `_pump` within the
firmware's buffers), retire it when it is acknowledged (`_retire`: its event, a refused batch's
rest cancelled), say the handshake's M110, and fail the session (`fail`). Recovery from lost
lines and lost oks (recovery.py) and the public sans-IO protocol (linestate.py) build on it;
no port, thread or clock here either.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import dataclass, field

from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import errors as E
from neatskin.marlin.deadlines import MotionTracker
from neatskin.marlin.jobs import Acknowledged, DriverConfig, Event, Failed, Job
from neatskin.marlin.replies import PROBE_TAG, frame
from neatskin.marlin.resends import ResendState

log = logging.getLogger(__name__)


@dataclass(eq=False)
class SentLine:
    """A line written to the printer: number, frame and deadlines, the job it carries (None: a probe), what came back."""

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
BOOT_SETTLE_S = 0.05  # after `start`, let the banner finish before the handshake


class LineSession:
    """The state of one session and the steps that change it; LineProtocol (linestate.py) is the public face."""

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
        self._inflight: list[SentLine] = []
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
        self._history: dict[int, SentLine] = {}  # recently acknowledged lines, for a firmware that never took them
        self._resend = ResendState(self.config.ok_after_resend)
        self._advanced_ok_seen = False
        self._foreign_ok: int | None = None  # under the handshake: the latest `ok N..` naming another line
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
        self._resend.due = now + BOOT_SETTLE_S
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

    def _send_line(self, job: Job | None, *, now: float, probe: bool = False, m110: bool = False) -> SentLine:
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
        line = SentLine(n, command, frame(command, n), job, deadline, deadline + self.config.max_busy_s, probe, m110)
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

    # ---- acknowledging ------------------------------------------------------------------------

    def _retire(self, line: SentLine, now: float) -> None:
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

    def _cancel_batch(self, refused: SentLine) -> None:
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

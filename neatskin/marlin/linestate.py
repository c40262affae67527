"""The Marlin line protocol as a sans-IO state machine: bytes and time in, bytes to write and finished jobs out.

`LineProtocol` is the machine's public face: through its layers it keeps every piece of protocol state (line
numbers, the lines in flight, resends, deadlines, lost-`ok` probes, the connect handshake) and touches no port,
thread or clock: the
caller feeds it what the printer said (`receive(data, now)`), the passing of time (`tick(now)`)
and work (`start_session`, `submit`), and takes the bytes to write (`data_to_send()`) and how
jobs ended (`events()`: Acknowledged or Failed, as h11 returns events; a Job is never mutated). Every wait it keeps has a
deadline and every retry a cap, so a hostile peer ends in one MarlinError, never a loop.
The transport around it (driver.py, link.py) owns the port, the reader thread and the clock.
This module is the public face and the reading of replies; the machine is one class in three
layers: the session's state and its send/acknowledge/fail steps (session.py), the recovery of
lost lines and lost oks (recovery.py), and this (values live in jobs.py).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

from neatskin.errors import ConfigError
from neatskin.marlin import errors as E
from neatskin.marlin.jobs import Event, Failed, Job
from neatskin.marlin.recovery import Recovery
from neatskin.marlin.replies import Kind, Reply, classify
from neatskin.marlin.session import BOOT_SETTLE_S

log = logging.getLogger(__name__)

_MAX_LINE_BYTES = 4096  # a reply line longer than this is garbage


class LineProtocol(Recovery):
    """Marlin's host protocol, one session at a time; see the module docstring for the contract."""

    # ---- inputs -----------------------------------------------------------------------------

    def start_session(self, now: float, boot_timeout_s: float | None = None) -> Job:
        """Begin a session: wait for `start` (or boot_timeout_s), then `M110 N0`; the returned job is the handshake."""
        self.reset(now)
        wait_s = self.config.boot_timeout_s if boot_timeout_s is None else boot_timeout_s
        if not math.isfinite(wait_s):  # nan or inf: the boot wait would never end on a silent port
            raise ConfigError(
                f"the boot wait is {wait_s!r} s; it must be a finite number of seconds",
                field="boot_timeout_s",
                fix="give the connect timeout a finite number of seconds (e.g. 5)",
            )
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
            settle = None if self._boot_seen_s is None else self._boot_seen_s + BOOT_SETTLE_S
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
            settled = self._boot_seen_s is not None and now >= self._boot_seen_s + BOOT_SETTLE_S
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
        if reply.number is not None and reply.number >= self._next_n and self._phase == "session":
            # Marlin's ADVANCED_OK copies N from the line it ran: this line was never sent in this session (its
            # M110 N0 began the numbering at 0)
            self._fail_here(
                E.OutOfStep,
                f"the printer said {reply.text!r}, acknowledging line N{reply.number}, but the last line sent "
                f"in this session was N{self._next_n - 1}",
            )
            return
        if not self._inflight:
            self.stats["stray_oks"] += 1
            return
        head = self._inflight[0]
        if reply.buffer_free is not None:
            self._queue_free = reply.buffer_free
        if reply.number is not None:  # ADVANCED_OK names the line: Marlin copies it from the line it ran
            if head.m110 and reply.number != head.n:
                # the ok of a line from before this session (a host that left lines in the firmware's queue runs
                # them first): only the M110's own ok starts the session
                self.stats["stale_oks"] += 1
                self._foreign_ok = reply.number
                return
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

"""How a Marlin session recovers what the line lost: lines the firmware asks for again, `ok`s that never came.

`Recovery` adds to the session's state (session.py) the two ways back to a line in step: a
`Resend: n` (fresh, duplicate or stale; its replay once the dialect's `ok` came or its wait ran
out; the caps that end a resend loop) and a lost `ok` (a line overdue gets a probe, `M118 E1
neatskin-probe N` or M114 on a firmware without M118's echo, whose answer proves every line
before it ran; the probes per stall are capped). linestate.py feeds it the replies.
"""

from __future__ import annotations

import logging

from neatskin.marlin import errors as E
from neatskin.marlin.replies import PROBE_TAG, frame
from neatskin.marlin.session import LineSession, SentLine

log = logging.getLogger(__name__)


class Recovery(LineSession):
    """Resends and lost-ok probes over a LineSession; LineProtocol (linestate.py) calls them from its replies and ticks."""

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

    def _overdue(self, head: SentLine, now: float) -> None:
        if head.probe and head.echoed:  # the probe ran; its own ok was lost
            self.stats["oks_recovered"] += 1
            self._retire(head, now)
            self._pump(now)
            return
        if head.m110:  # M110 is idempotent: say it again
            self._resend.counts[head.n] += 1
            if self._resend.counts[head.n] > self.config.probe_attempts and self._foreign_ok is not None:
                self._fail_here(
                    E.OutOfStep,
                    f"{head.command!r} (line N{head.n}) was sent {self._resend.counts[head.n]} times and every `ok` "
                    f"named another line (the latest N{self._foreign_ok}), never the handshake's",
                )
                return
            if self._resend.counts[head.n] > self.config.probe_attempts:
                self._fail_here(
                    E.NoAnswer,
                    f"no answer to {head.command!r} within {self.config.min_timeout_s:g} s, "
                    f"{self._resend.counts[head.n]} times",
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

"""The resend bookkeeping of one Marlin session: what was asked for again, when to replay it, and the dialect.

`ResendState` is the part of `LineProtocol`'s state that only resends read and write: the replay
pending and when it is due, whether an `ok` came after the latest `Resend:`, the firmware's dialect
(does an `ok` follow `Resend:`?) as known or learned, the communication errors seen and the line
the firmware named with the latest, the last request served (to tell a duplicate from a fresh
refusal), and the caps' counters. A new session gets a new one.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field


@dataclass
class ResendState:
    ok_after: bool | None  # the dialect: an `ok` follows `Resend:` (None: not known yet, learned)
    pending: int | None = None  # the line to replay from, once due
    due: float = 0.0
    ok_seen: bool = False  # an `ok` came while the replay was pending
    without_ok: int = 0  # resends that saw no `ok`, while learning the dialect
    comm_errors: int = 0
    fw_last_line: int | None = None  # the firmware's `Last Line:` with the latest communication error
    served: tuple[int | None, int, float] = (None, -1, 0.0)  # (line, comm_errors at the time, time) last replayed
    stale_streak: int = 0  # requests in a row for lines already acknowledged
    counts: collections.Counter[int] = field(default_factory=collections.Counter)  # requests per line

    def wait_s(self, grace_s: float, min_timeout_s: float) -> float:
        """How long to wait for the dialect's `ok` after `Resend:` before replaying."""
        if self.ok_after is None:
            return grace_s
        return min_timeout_s if self.ok_after else 0.0

    def fresh_error_for(self, n: int) -> bool:
        """Whether a communication error came since the last replay served, naming the line before n."""
        return (
            0 < self.comm_errors
            and self.comm_errors > self.served[1]
            and (self.fw_last_line is None or self.fw_last_line == n - 1)
        )

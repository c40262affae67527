"""The values between a caller and the Marlin line protocol: DriverConfig (every timing knob and cap), Job
(a command submitted) and the events that say how a job ended (Acknowledged, Failed), as h11 returns
events: the protocol (linestate.LineProtocol) never mutates what the caller handed it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from neatskin.errors import ConfigError
from neatskin.gcode.parse import GcodeLine
from neatskin.marlin import errors as E


@dataclass(frozen=True)
class DriverConfig:
    boot_timeout_s: float = 3.0  # wait this long for `start` after opening; then go on without it
    min_timeout_s: float = 2.0  # the least time any line may take to be acknowledged
    busy_extension_s: float = 6.0  # a `busy:` pushes the deadline to now + this (Marlin sends one every 2 s)
    max_busy_s: float = 900.0  # keep-alives cannot stretch one line's wait beyond this
    probe_attempts: int = 3  # lost-ok probes per stall before NoAnswer
    max_resends: int = 12  # the same line asked for this often -> ResendLoop
    resend_grace_s: float = 0.02  # while the dialect is unknown: wait this long for an `ok` after `Resend:`
    duplicate_resend_s: float = 1.0  # an identical `Resend: n` with no new error within this is a duplicate
    # the read timeout of a port read through pyserial's API (the raw pty/tty channel sleeps until the
    # protocol's next deadline instead): how late a deadline may be noticed there
    poll_s: float = 0.02
    write_timeout_s: float = 5.0  # a write that finds no room for this long: PortDead
    max_in_flight: int = 1  # >1 pipelines lines, only once the firmware's `ok N.. P.. B..` names them
    # without a profile or an explicit rx_buffer_size: Marlin's stock RX_BUFFER_SIZE less one
    rx_buffer_bytes: int = 127
    homing_time_s: float = 60.0
    default_feed_mm_s: float = 25.0
    motion_time_scale: float = 1.0  # real seconds per second of motion: 0 for a virtual-time simulated printer
    connect_attempts: int = 8  # M110 said this often (after `start`, `Resend:`) -> ConnectFailed
    connect_timeout_s: float = 30.0  # the handshake after the boot wait ends within this -> ConnectFailed
    ok_after_resend: bool | None = None  # the firmware's dialect: None learns it from the first resends
    # end each batch (send_lines, send) with a probe whose echo proves every line ran: True always,
    # None once the printer has sent an `ok` that acknowledged nothing (it duplicates oks), False never
    confirm_batches: bool | None = None

    def __post_init__(self) -> None:
        # a deadline of nan or inf is never reached: a silent port would be waited on for ever
        positive = ("boot_timeout_s", "min_timeout_s", "busy_extension_s", "max_busy_s", "poll_s")
        for name in (*positive, "write_timeout_s", "connect_timeout_s", "homing_time_s", "default_feed_mm_s"):
            _check_seconds(name, getattr(self, name), positive=True)
        for name in ("resend_grace_s", "duplicate_resend_s", "motion_time_scale"):
            _check_seconds(name, getattr(self, name), positive=False)
        for name in ("probe_attempts", "max_resends", "connect_attempts", "max_in_flight"):
            if getattr(self, name) < 1:
                raise ConfigError(
                    f"DriverConfig.{name} is {getattr(self, name)!r}; it must be >= 1",
                    field=name,
                    fix=f"give {name} a whole number of 1 or more",
                )


def _check_seconds(name: str, value: float, *, positive: bool) -> None:
    """One DriverConfig time (or scale): a finite number, > 0 (or >= 0 where 0 means "none"), else ConfigError."""
    ok = isinstance(value, int | float) and math.isfinite(value) and (value > 0 if positive else value >= 0)
    if not ok:
        bound = "> 0" if positive else ">= 0"
        raise ConfigError(
            f"DriverConfig.{name} is {value!r}; it must be a finite number {bound}",
            field=name,
            fix=f"give {name} a finite number {bound} (e.g. {DriverConfig.__dataclass_fields__[name].default!r})",
        )


@dataclass(frozen=True, eq=False)
class Job:
    """One command a caller submits; the protocol reports how it ended as an event (Acknowledged or Failed).
    Compared by identity: the same command twice is two jobs."""

    command: str
    parsed: GcodeLine | None = None  # the parsed line, when the caller parsed it already
    batch: object | None = None  # jobs of one send_lines call share it: a refusal cancels the rest
    barrier: bool = False  # a probe whose echo proves that every line before it ran


class Acknowledged(NamedTuple):
    """The printer acknowledged the job's line: what it printed before the `ok` (and data on the ok itself),
    and its refusal text when it refused the command (`Unknown command`, `Home XYZ First`). A NamedTuple:
    one is made per line, on the hot path."""

    job: Job
    line: int | None
    replies: tuple[str, ...] = ()
    rejected: str | None = None


class Failed(NamedTuple):
    """The job will not be acknowledged: the session failed, or it was taken back before it was sent."""

    job: Job
    error: E.MarlinError


Event = Acknowledged | Failed

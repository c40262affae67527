"""How long a line may take before its `ok` is overdue: the motion a command implies, from the host's side.

The host steps the one G-code machine model (gcode.machine: G90/G91, G92, G28, G0/G1 targets
and feed) over the lines it sends to size each line's deadline: a move from its length and feed
(trapezoid at the profile's limits, or at a default acceleration without a profile), `G4` from
its dwell, `G28` from the homing time, and everything after a move waits at most until the
queued motion has run out (Marlin answers a full planner with a delayed `ok`). A move from a
position the host does not know yet is bounded by `unknown_travel_mm` on the slowest axis.
Upper bounds, never estimates to act on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from neatskin.errors import ConfigError
from neatskin.gcode.machine import Dwell, Home, Machine, Move, trapezoid_time_s
from neatskin.gcode.parse import GcodeLine, parse_line
from neatskin.gcode.profile import PrinterProfile


@dataclass
class MotionTracker:
    """The commanded position and modes, updated per line sent; `line_time_s` says how long it may run."""

    profile: PrinterProfile | None = None
    homing_time_s: float = 60.0
    default_feed_mm_s: float = 25.0
    accel_mm_s2: float = 200.0
    unknown_travel_mm: float = 500.0
    machine: Machine = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.profile is not None:
            self.homing_time_s = max(self.homing_time_s, self.profile.homing_time_s * 2)
        self.machine = Machine(
            self.profile,
            feed_mm_s=self.default_feed_mm_s,
            accel_mm_s2=self.accel_mm_s2,
            homing_time_s=self.homing_time_s,
        )

    @property
    def position_mm(self) -> list[float | None]:
        """The commanded logical position (None per axis until known)."""
        return list(self.machine.logical_mm)

    @property
    def absolute(self) -> bool:
        return self.machine.absolute

    @property
    def feed_mm_s(self) -> float:
        """The modal feed (the default until a line sets F)."""
        return self.machine.feed_mm_s

    def line_time_s(self, command: str | GcodeLine) -> tuple[float, bool]:
        """(seconds the command itself may take, whether it first waits for queued motion)."""
        try:
            line = parse_line(command) if isinstance(command, str) else command
        except ConfigError:
            return 0.0, True
        if line is None:
            return 0.0, False
        event = self.machine.step(line)
        if isinstance(event, Move):
            if event.duration_s is not None:
                return event.duration_s, False
            return self._bound(self.unknown_travel_mm, self.machine.feed_mm_s), False
        if isinstance(event, Home):
            return self.homing_time_s, True  # the host's bound, not the homing's share of axes
        if isinstance(event, Dwell):
            return event.duration_s, True
        return 0.0, True

    def _bound(self, distance_mm: float, feed_mm_s: float) -> float:
        # the slowest axis bounds the move when we do not know the direction
        if self.profile is None:
            return trapezoid_time_s(distance_mm, feed_mm_s, self.accel_mm_s2)
        feed = min(feed_mm_s, min(self.profile.max_feed_mm_s))
        return trapezoid_time_s(distance_mm, feed, min(self.profile.max_accel_mm_s2))

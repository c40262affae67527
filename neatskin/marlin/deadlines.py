"""How long a line may take before its `ok` is overdue: the motion a command implies, from the host's side.

The host follows the commanded position (G90/G91, G92, G28, G0/G1 targets and feed) to size
each line's deadline: a move from its length and feed (trapezoid at the profile's limits, or
a bound without a profile), `G4` from its dwell, `G28` from the homing time, and everything
after a move waits at most until the queued motion has run out (Marlin answers a full planner
with a delayed `ok`). Upper bounds, never estimates to act on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from neatskin.errors import ConfigError
from neatskin.gcode.motion import move_time_s, trapezoid_time_s
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
    position_mm: list[float | None] | None = None
    absolute: bool = True
    feed_mm_s: float | None = None

    def __post_init__(self) -> None:
        if self.position_mm is None:
            self.position_mm = [None, None, None]
        if self.profile is not None:
            self.homing_time_s = max(self.homing_time_s, self.profile.homing_time_s * 2)

    def line_time_s(self, command: str | GcodeLine) -> tuple[float, bool]:
        """(seconds the command itself may take, whether it first waits for queued motion)."""
        try:
            line = parse_line(command) if isinstance(command, str) else command
        except ConfigError:
            return 0.0, True
        if line is None:
            return 0.0, False
        code = line.code
        if code in ("G0", "G1"):
            return self._move(line), False
        if code == "G4":
            return (line.get("P", 0.0) or 0.0) / 1000.0 + (line.get("S", 0.0) or 0.0), True
        if code == "G28":
            self.position_mm = [0.0, 0.0, 0.0]
            return self.homing_time_s, True
        if code == "G90":
            self.absolute = True
        elif code == "G91":
            self.absolute = False
        elif code == "G92":
            for i, axis in enumerate("XYZ"):
                value = line.get(axis)
                if value is not None:
                    self.position_mm[i] = value
        return 0.0, True

    def _move(self, line) -> float:
        feed = line.get("F")
        if feed is not None and feed > 0:
            self.feed_mm_s = feed / 60.0
        feed_mm_s = self.feed_mm_s or self.default_feed_mm_s
        start = list(self.position_mm)
        end = list(start)
        unknown = False
        for i, axis in enumerate("XYZ"):
            value = line.get(axis)
            if value is None:
                continue
            if self.absolute:
                end[i] = value
            elif start[i] is not None:
                end[i] = start[i] + value
            else:
                unknown = True
        if unknown or any(s is None and e is not None for s, e in zip(start, end)):
            self.position_mm = end
            return self._bound(self.unknown_travel_mm, feed_mm_s)
        self.position_mm = end
        delta = [0.0 if s is None else e - s for s, e in zip(start, end)]
        if self.profile is not None:
            s3 = tuple(0.0 if s is None else s for s in start)
            return move_time_s(s3, tuple(a + d for a, d in zip(s3, delta)), feed_mm_s, self.profile)
        return self._bound(math.sqrt(sum(d * d for d in delta)), feed_mm_s)

    def _bound(self, distance_mm: float, feed_mm_s: float) -> float:
        # the slowest axis bounds the move when we do not know the direction
        slowest = min(self.profile.max_feed_mm_s) if self.profile is not None else feed_mm_s
        feed = min(feed_mm_s, slowest) if self.profile is not None else feed_mm_s
        accel = min(self.profile.max_accel_mm_s2) if self.profile is not None else self.accel_mm_s2
        return trapezoid_time_s(distance_mm, feed, accel)

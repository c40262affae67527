"""Motion-time estimates of a G-code program: the machine model's moves, dwells and homing, summed.

The interpreter and the kinematics live in gcode.machine (one for the whole toolkit). A move of
length d at nominal feed v with acceleration a accelerates, cruises, and decelerates; when d is
too short to reach v the profile is triangular. As in
Marlin's planner, the nominal feed and the acceleration of a move are limited so that no axis
exceeds its own maximum (a pure Z move runs at the Z limits). Every move here starts and ends
at rest (M400 between phases forces that on the real printer anyway; for chained travel moves
it is a slight over-estimate of Marlin's junction blending).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from neatskin.gcode.machine import Dwell, Home, Machine, Move
from neatskin.gcode.parse import GcodeLine, parse_line
from neatskin.gcode.profile import PrinterProfile


@dataclass(frozen=True)
class TimeEstimate:
    """Where a program's time goes, in seconds, and what it does."""

    motion_s: float
    dwell_s: float
    homing_s: float
    moves: int
    path_mm: float
    travel_xy_mm: float  # horizontal path length (the part travel ordering can shorten)

    @property
    def total_s(self) -> float:
        return self.motion_s + self.dwell_s + self.homing_s


_UNPARSED = object()
_PARSE_CACHE_LINES = 4096  # distinct lines kept parsed per clock: the repeated ones come first


class MotionClock:
    """Steps through commands one at a time on the machine model (gcode.machine), summing the program's time.

    `step(line)` returns the seconds that command takes and accumulates the program's totals.
    Before a G28 the position is unknown; it starts at `start_mm` (default: the park position).
    """

    def __init__(self, profile: PrinterProfile, start_mm: tuple[float, float, float] | None = None) -> None:
        self.profile = profile
        start = start_mm if start_mm is not None else tuple(profile.park_mm)
        self.machine = Machine(
            profile, start_mm=start, feed_mm_s=profile.travel_feed_mm_s, homing_time_s=profile.homing_time_s
        )
        self.motion_s = self.dwell_s = self.homing_s = self.path_mm = self.travel_xy_mm = 0.0
        self.moves = 0
        self._parsed: dict[str, GcodeLine | None] = {}

    def _parse(self, text: str) -> GcodeLine | None:
        """parse_line, once per distinct text (a press program repeats most of its lines: `M400`, the
        descend and lift moves); an echo (`M118 ...`, never a motion, never a syntax error without a
        `*`) is not parsed at all."""
        if text.startswith("M118 ") and "*" not in text:
            return None
        cached = self._parsed.get(text, _UNPARSED)
        if cached is not _UNPARSED:
            return cached  # type: ignore[return-value]
        line = parse_line(text)
        if len(self._parsed) < _PARSE_CACHE_LINES:
            self._parsed[text] = line
        return line

    def step(self, item: GcodeLine | str) -> float:
        line = self._parse(item) if isinstance(item, str) else item
        if line is None:
            return 0.0
        event = self.machine.step(line)
        if isinstance(event, Move):
            if not event.length_mm > 0 or event.duration_s is None:
                return 0.0
            start, end = event.start_mm, event.end_mm
            self.motion_s += event.duration_s
            self.path_mm += event.length_mm
            self.travel_xy_mm += math.hypot(end[0] - start[0], end[1] - start[1])  # type: ignore[operator]
            self.moves += 1
            return event.duration_s
        if isinstance(event, Dwell):
            self.dwell_s += event.duration_s
            return event.duration_s
        if isinstance(event, Home):
            self.homing_s += event.duration_s
            return event.duration_s
        return 0.0

    def estimate(self) -> TimeEstimate:
        return TimeEstimate(self.motion_s, self.dwell_s, self.homing_s, self.moves, self.path_mm, self.travel_xy_mm)


def estimate_program_time(
    lines: Iterable[GcodeLine | str], profile: PrinterProfile, start_mm: tuple[float, float, float] | None = None
) -> TimeEstimate:
    """Estimate a program's run time: G0/G1 (G90/G91, G92, modal F in mm/min), G4 P/S dwells, G28 homing."""
    clock = MotionClock(profile, start_mm)
    for line in lines:
        clock.step(line)
    return clock.estimate()


def phase_durations_s(program, profile: PrinterProfile) -> np.ndarray:
    """Printer time of every phase of every press, shape (presses, phases), in execution order
    (the preamble's homing included in the state, not in the result): the runner's ETA and timeouts."""
    clock = MotionClock(profile)
    for line in program.preamble:
        clock.step(line)
    # one pass over the presses: a block is formatted when asked for (gcode.blocks), so a second pass for the
    # phase count would format every press again
    rows = [[sum(clock.step(line) for line in phase.lines) for phase in block.phases] for block in program.presses]
    out = np.zeros((len(rows), max((len(row) for row in rows), default=0)))
    for i, row in enumerate(rows):
        out[i, : len(row)] = row
    return out

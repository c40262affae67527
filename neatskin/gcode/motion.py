"""Motion-time estimates: trapezoidal velocity profiles per move, summed over a G-code program.

A move of length d at nominal feed v with acceleration a accelerates from v_start, cruises,
and decelerates to v_end; when d is too short to reach v the profile is triangular. As in
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

from neatskin.gcode.parse import GcodeLine, parse_line
from neatskin.gcode.profile import PrinterProfile


def trapezoid_time_s(
    distance_mm: float, feed_mm_s: float, accel_mm_s2: float, v_start_mm_s: float = 0.0, v_end_mm_s: float = 0.0
) -> float:
    """Time of one move under a trapezoidal (or, if the feed is not reached, triangular) profile."""
    if distance_mm < 0 or not math.isfinite(distance_mm):
        raise ValueError(f"distance_mm must be finite and >= 0, got {distance_mm}")
    if feed_mm_s <= 0 or accel_mm_s2 <= 0:
        raise ValueError(f"feed_mm_s and accel_mm_s2 must be > 0, got {feed_mm_s}, {accel_mm_s2}")
    if not (0 <= v_start_mm_s <= feed_mm_s and 0 <= v_end_mm_s <= feed_mm_s):
        raise ValueError(f"v_start_mm_s and v_end_mm_s must lie in [0, feed], got {v_start_mm_s}, {v_end_mm_s}")
    if distance_mm == 0:
        return 0.0
    a, v, vs, ve = accel_mm_s2, feed_mm_s, v_start_mm_s, v_end_mm_s
    d_accel = (v * v - vs * vs) / (2 * a)
    d_decel = (v * v - ve * ve) / (2 * a)
    if d_accel + d_decel <= distance_mm:
        return (v - vs) / a + (v - ve) / a + (distance_mm - d_accel - d_decel) / v
    v_peak_sq = a * distance_mm + (vs * vs + ve * ve) / 2
    if v_peak_sq < max(vs, ve) ** 2 - 1e-12:
        raise ValueError(f"cannot change speed from {vs} to {ve} mm/s within {distance_mm} mm at {a} mm/s^2")
    v_peak = math.sqrt(max(v_peak_sq, max(vs, ve) ** 2))
    return (v_peak - vs) / a + (v_peak - ve) / a


def limited_feed_and_accel(
    delta_mm: tuple[float, float, float], feed_mm_s: float, profile: PrinterProfile
) -> tuple[float, float]:
    """Nominal feed and acceleration along a move, scaled so no axis exceeds its maximum."""
    length = math.sqrt(sum(d * d for d in delta_mm))
    if length == 0:
        return feed_mm_s, profile.accel_mm_s2
    feed, accel = feed_mm_s, profile.accel_mm_s2
    for d, vmax, amax in zip(delta_mm, profile.max_feed_mm_s, profile.max_accel_mm_s2):
        share = abs(d) / length
        if share > 0:
            feed = min(feed, vmax / share)
            accel = min(accel, amax / share)
    return feed, accel


def move_time_s(
    start_mm: tuple[float, float, float], end_mm: tuple[float, float, float], feed_mm_s: float, profile: PrinterProfile
) -> float:
    """Time of one linear move from rest to rest."""
    delta = tuple(e - s for s, e in zip(start_mm, end_mm))
    feed, accel = limited_feed_and_accel(delta, feed_mm_s, profile)
    return trapezoid_time_s(math.sqrt(sum(d * d for d in delta)), feed, accel)


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


class MotionClock:
    """Steps through commands one at a time, keeping position, G90/G91 and the modal feed.

    `step(line)` returns the seconds that command takes and accumulates the program's totals.
    Before a G28 the position is unknown; it starts at `start_mm` (default: the park position).
    """

    def __init__(self, profile: PrinterProfile, start_mm: tuple[float, float, float] | None = None) -> None:
        self.profile = profile
        self.pos = list(start_mm if start_mm is not None else tuple(profile.park_mm))
        self.feed_mm_s = profile.travel_feed_mm_s
        self.relative = False
        self.motion_s = self.dwell_s = self.homing_s = self.path_mm = self.travel_xy_mm = 0.0
        self.moves = 0

    def step(self, item: GcodeLine | str) -> float:
        line = parse_line(item) if isinstance(item, str) else item
        if line is None:
            return 0.0
        code, profile = line.code, self.profile
        if code in ("G0", "G1"):
            f = line.get("F")
            if f is not None and f > 0:
                self.feed_mm_s = f / 60.0
            target = list(self.pos)
            for k, letter in enumerate("XYZ"):
                value = line.get(letter)
                if value is not None:
                    target[k] = self.pos[k] + value if self.relative else value
            delta = [t - p for t, p in zip(target, self.pos)]
            length = math.sqrt(sum(d * d for d in delta))
            seconds = 0.0
            if length > 0:
                seconds = move_time_s(tuple(self.pos), tuple(target), self.feed_mm_s, profile)
                self.motion_s += seconds
                self.path_mm += length
                self.travel_xy_mm += math.hypot(delta[0], delta[1])
                self.moves += 1
            self.pos = target
            return seconds
        if code == "G4":
            p_ms, s_s = line.get("P"), line.get("S")
            seconds = (p_ms / 1000.0 if p_ms is not None else 0.0) + (s_s if s_s is not None else 0.0)
            self.dwell_s += seconds
            return seconds
        if code == "G28":
            self.homing_s += profile.homing_time_s
            self.pos = [profile.soft_min_mm.x, profile.soft_min_mm.y, profile.soft_min_mm.z]
            return profile.homing_time_s
        if code in ("G90", "G91"):
            self.relative = code == "G91"
        elif code == "G92":
            for k, letter in enumerate("XYZ"):
                value = line.get(letter)
                if value is not None:
                    self.pos[k] = value
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
    n_phases = max((len(b.phases) for b in program.presses), default=0)
    out = np.zeros((len(program.presses), n_phases))
    for i, block in enumerate(program.presses):
        for j, phase in enumerate(block.phases):
            out[i, j] = sum(clock.step(line) for line in phase.lines)
    return out

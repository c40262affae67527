"""The simulated printer's motion: a timeline of trapezoidal moves, and where the probe is at any time.

Each move comes from the one G-code machine model (gcode.machine: the feed and acceleration
scaled so no axis exceeds its maximum, the rest-to-rest trapezoid time) and starts when the
previous one ends (rest to rest, as the gcode.motion estimates assume). `position_mm(t_s)` interpolates the trapezoid exactly, so the
simulated skin and FSR see the press as it happens.
"""

from __future__ import annotations

import bisect
import functools
import math
from typing import NamedTuple

import numpy as np

from neatskin.gcode.machine import Move, limited_feed_and_accel, trapezoid_time_s
from neatskin.gcode.profile import PrinterProfile

Xyz = tuple[float, float, float]


class Segment(NamedTuple):
    """One move from p0_mm to p1_mm over [t0_s, t1_s]; `linear` for homing (constant speed).

    An immutable NamedTuple rather than a frozen dataclass: one is built per move on the simulated
    printer's hot path."""

    t0_s: float
    t1_s: float
    p0_mm: Xyz
    p1_mm: Xyz
    feed_mm_s: float
    accel_mm_s2: float
    linear: bool = False
    duration_s: float | None = None  # the move's own time (t1_s - t0_s before rounding to the clock's origin)

    @property
    def own_duration_s(self) -> float:
        return self.t1_s - self.t0_s if self.duration_s is None else self.duration_s

    @property
    def length_mm(self) -> float:
        return math.dist(self.p0_mm, self.p1_mm)

    def position_mm(self, t_s: float) -> Xyz:
        if t_s <= self.t0_s:
            return self.p0_mm
        if t_s >= self.t1_s or self.length_mm == 0:
            return self.p1_mm
        d = self.length_mm
        tau = t_s - self.t0_s
        if self.linear:
            s = d * tau / (self.t1_s - self.t0_s)
        else:
            s = trapezoid_distance_mm(tau, d, self.feed_mm_s, self.accel_mm_s2)
        f = s / d
        return tuple(a + (b - a) * f for a, b in zip(self.p0_mm, self.p1_mm))  # type: ignore[return-value]


def trapezoid_distance_mm(t_s: float, distance_mm: float, feed_mm_s: float, accel_mm_s2: float) -> float:
    """Distance covered t_s after starting a rest-to-rest trapezoidal move (the inverse of its timing)."""
    a = accel_mm_s2
    v = min(feed_mm_s, math.sqrt(a * distance_mm))
    t_a = v / a
    d_a = v * v / (2 * a)
    t_c = max(0.0, (distance_mm - 2 * d_a) / v)
    if t_s <= 0:
        return 0.0
    if t_s < t_a:
        return 0.5 * a * t_s * t_s
    if t_s < t_a + t_c:
        return d_a + v * (t_s - t_a)
    td = min(t_s - t_a - t_c, t_a)
    return min(distance_mm, d_a + v * t_c + v * td - 0.5 * a * td * td)


class HistoryForgotten(LookupError):
    """A question about a time before the oldest move a Timeline still keeps."""


class Timeline:
    """The printer's recent moves, in order; `end_s` is when the last queued one finishes.

    Memory stays flat however long a campaign runs: the timeline keeps the latest `keep_segments`
    moves (trimmed in blocks of an eighth of that, so the cost per move stays constant), and `forget_before(t_s)` lets
    a caller drop what it will never ask about. The firmware itself only asks about now and later;
    a question about a time older than what is kept raises HistoryForgotten, never a wrong answer.
    """

    def __init__(self, profile: PrinterProfile, start_mm: Xyz, keep_segments: int = 4096) -> None:
        if keep_segments < 2:
            raise ValueError(f"keep_segments must be >= 2, got {keep_segments}")
        self.profile = profile
        self.start_mm = start_mm
        self.keep_segments = keep_segments
        self.segments: list[Segment] = []
        self._t0s: list[float] = []
        self._t1s: list[float] = []  # non-decreasing: every segment starts when the previous one ends
        self.forgotten = 0  # moves dropped from the front so far
        self.forgotten_until_s = -math.inf  # no question about a time before this can be answered any more

    @property
    def end_s(self) -> float:
        return self.segments[-1].t1_s if self.segments else 0.0

    @property
    def end_mm(self) -> Xyz:
        return self.segments[-1].p1_mm if self.segments else self.start_mm

    def pending(self, t_s: float) -> int:
        """Moves queued and not finished at t_s (the planner's occupied slots)."""
        t1s = self._t1s
        if not t1s or t1s[-1] <= t_s:
            return 0
        return len(t1s) - bisect.bisect_right(t1s, t_s)

    def slot_free_s(self, t_s: float, slots: int) -> float:
        """The earliest time >= t_s at which fewer than `slots` moves are pending."""
        if self.pending(t_s) < slots:
            return t_s
        return self.segments[-slots].t1_s

    def add(self, now_s: float, move: Move) -> Segment:
        """Queue a move of the machine model (known start, end and duration) after the last one."""
        t0 = now_s if now_s > self.end_s else self.end_s
        duration = move.duration_s or 0.0
        return self._append(
            Segment(t0, t0 + duration, move.start_mm, move.end_mm, move.feed_mm_s, move.accel_mm_s2, False, duration)  # type: ignore[arg-type]
        )

    def add_move(self, now_s: float, target_mm: Xyz, feed_mm_s: float) -> Segment:
        start = self.end_mm
        delta = (target_mm[0] - start[0], target_mm[1] - start[1], target_mm[2] - start[2])
        feed, accel = limited_feed_and_accel(delta, feed_mm_s, self.profile)
        length = math.sqrt(sum(d * d for d in delta))
        t0 = max(now_s, self.end_s)
        duration = trapezoid_time_s(length, feed, accel) if length > 0 else 0.0
        return self._append(Segment(t0, t0 + duration, start, target_mm, feed, accel, False, duration))

    def add_homing(self, now_s: float, home_mm: Xyz, duration_s: float) -> Segment:
        t0 = max(now_s, self.end_s)
        return self._append(Segment(t0, t0 + duration_s, self.end_mm, home_mm, 1.0, 1.0, True, duration_s))

    def teleport(self, now_s: float, position_mm: Xyz) -> None:
        """A reset (power cycle): the probe stays where it was, nothing is queued any more."""
        here = self.position_mm(now_s)
        self.forgotten += len(self.segments)
        if self.segments:
            self.forgotten_until_s = max(self.forgotten_until_s, now_s)
        self.segments = [Segment(now_s, now_s, here, position_mm, 1.0, 1.0, True, 0.0)]
        self._t0s = [now_s]
        self._t1s = [now_s]

    def _append(self, segment: Segment) -> Segment:
        self.segments.append(segment)
        self._t0s.append(segment.t0_s)
        self._t1s.append(segment.t1_s)
        if len(self.segments) >= self.keep_segments + max(1, self.keep_segments // 8):
            self._drop(len(self.segments) - self.keep_segments)
        return segment

    def forget_before(self, t_s: float) -> int:
        """Drop the moves that ended before t_s, except the one the probe rests after at t_s
        (`segments_from(t_s)` and `position_mm(t >= t_s)` stay answerable); the number dropped."""
        k = bisect.bisect_right(self._t1s, t_s) - 1  # the last move ended by t_s: it stays
        k = min(k, len(self.segments) - 1)
        if k <= 0:
            return 0
        self._drop(k)
        return k

    def _drop(self, k: int) -> None:
        self.forgotten_until_s = max(self.forgotten_until_s, self.segments[k - 1].t1_s)
        self.forgotten += k
        del self.segments[:k], self._t0s[:k], self._t1s[:k]

    def _check(self, t_s: float) -> None:
        if t_s < self.forgotten_until_s:
            raise HistoryForgotten(
                f"printer time {t_s:.6f} s is before the oldest move kept (ended {self.forgotten_until_s:.6f} s; "
                f"{self.forgotten} moves forgotten, the latest {self.keep_segments} kept): "
                "ask while the press is recent, or raise keep_segments"
            )

    def segments_from(self, t0_s: float) -> list[Segment]:
        """The moves from the one the probe rests after at t0_s onwards (all of them if none ended by t0_s)."""
        k = bisect.bisect_right(self._t1s, t0_s)  # moves [0, k) ended by t0_s; the probe rests after k - 1
        if k == 0 and self.forgotten:  # the move the probe rested after is gone
            self._check(min(t0_s, self.forgotten_until_s - 1e-9))
        return self.segments[max(k - 1, 0) :]

    def position_mm(self, t_s: float) -> Xyz:
        i = bisect.bisect_right(self._t0s, t_s) - 1
        if i < 0:
            self._check(t_s)
            return self.segments[0].p0_mm if self.segments else self.start_mm
        return self.segments[i].position_mm(t_s)


GAP_GRID_S = 1e-6  # waits between moves are dwells (G4 P in ms, S in s): on this grid, whatever the clock's origin


def relative_segments(segments: list[Segment], t0_s: float) -> list[Segment]:
    """`segments` (the first one ended by t0_s) on a clock that starts at t0_s, with times that depend only on
    the moves' own durations and the dwells between them, not on the absolute time t0_s (a resumed printer
    counts from another origin, and `t1_s - t0_s` of an absolute timeline rounds differently there)."""
    if not segments:
        return []
    first = segments[0]
    end = -round((t0_s - first.t1_s) / GAP_GRID_S) * GAP_GRID_S if first.t1_s <= t0_s else first.t1_s - t0_s
    out = [first._replace(t0_s=end - first.own_duration_s, t1_s=end, duration_s=first.own_duration_s)]
    for prev, seg in zip(segments, segments[1:]):
        start = end + round((seg.t0_s - prev.t1_s) / GAP_GRID_S) * GAP_GRID_S
        end = start + seg.own_duration_s
        out.append(seg._replace(t0_s=start, t1_s=end, duration_s=seg.own_duration_s))
    return out


def positions_mm(segments, times_s: np.ndarray) -> np.ndarray:
    """Probe position (times, 3) along `segments` (in time order), vectorised over many times:
    `Segment.position_mm` / `Timeline.position_mm` for a whole acquisition's sample clock at once.
    Between moves the probe rests where the last one ended."""
    times_s = np.asarray(times_s, dtype=float)
    out = np.empty(times_s.shape + (3,))
    if not segments:
        out[:] = np.nan
        return out
    t0s = np.array([seg.t0_s for seg in segments])
    index = np.searchsorted(t0s, times_s, side="right") - 1
    out[index < 0] = segments[0].p0_mm
    for k in np.unique(index[index >= 0]):
        seg = segments[k]
        mask = index == k
        p0, p1 = np.asarray(seg.p0_mm, float), np.asarray(seg.p1_mm, float)
        frac = segment_fraction(seg, np.clip(times_s[mask] - seg.t0_s, 0.0, None))
        out[mask] = p0 + frac[:, None] * (p1 - p0)
    return out


def segment_fraction(seg, tau: np.ndarray, *, ordered: bool = False) -> np.ndarray:
    """The share of the move's length covered tau >= 0 seconds after it started (any order of tau): linear,
    or the trapezoid of accelerating, cruising and braking, each time by its own phase's expression.

    ordered: tau is one increasing run without NaN (a sample clock), so each phase's times are one slice: the
    same expressions on slices instead of masks (`ordered_fraction`, the same bits, tested)."""
    constants = move_constants(seg)
    if ordered and tau.ndim == 1 or constants[0] != "trapezoid":
        return ordered_fraction(constants, np.array(tau, dtype=float))
    _, length, a, v, t_a, d_a, t_c = constants
    accel = tau < t_a
    cruise = ~accel & (tau < t_a + t_c)
    brake = ~accel & ~cruise  # what is neither (NaN included), as np.where's else-branch
    dist = np.empty_like(tau)
    dist[accel] = 0.5 * a * tau[accel] * tau[accel]
    dist[cruise] = d_a + v * (tau[cruise] - t_a)
    td = np.clip(tau[brake] - t_a - t_c, 0.0, t_a)
    dist[brake] = d_a + v * t_c + v * td - 0.5 * a * td * td
    return np.minimum(dist, length) / length


@functools.lru_cache(maxsize=64)
def move_constants(seg) -> tuple:
    """What segment_fraction needs of a move before it looks at the times (cached: a paper campaign's 28 repeats of a
    position share their moves): ("still",) for a move of no length
    or time, ("linear", duration), or ("trapezoid", length, a, v, t_a, d_a, t_c)."""
    length = float(np.linalg.norm(np.asarray(seg.p1_mm, float) - np.asarray(seg.p0_mm, float)))
    duration = seg.own_duration_s
    if length == 0 or duration <= 0:
        return ("still",)
    if seg.linear:
        return ("linear", duration)
    a = seg.accel_mm_s2
    v = min(seg.feed_mm_s, float(np.sqrt(a * length)))
    t_a, d_a = v / a, v * v / (2 * a)
    t_c = max(0.0, (length - 2 * d_a) / v)
    return ("trapezoid", length, a, v, t_a, d_a, t_c)


def ordered_fraction(constants: tuple, tau: np.ndarray) -> np.ndarray:
    """segment_fraction(seg, tau, ordered=True) for tau >= 0, increasing, finite; `tau` is overwritten."""
    kind = constants[0]
    if kind == "still":
        return np.ones_like(tau)
    if kind == "linear":
        np.divide(tau, constants[1], out=tau)
        return np.minimum(tau, 1.0, out=tau)
    _, length, a, v, t_a, d_a, t_c = constants
    dist = np.empty_like(tau)
    i_c, i_b = int(tau.searchsorted(t_a)), int(tau.searchsorted(t_a + t_c))  # the first cruising, braking
    i_b = max(i_b, i_c)
    half_a = 0.5 * a
    # each phase only where it has times: a sample clock cut to the skin (below_runs) often starts braking
    if i_c:
        head = dist[:i_c]
        np.multiply(tau[:i_c], half_a, out=head)  # 0.5 * a * tau * tau, left to right
        np.multiply(head, tau[:i_c], out=head)
    if i_b > i_c:
        cruise = dist[i_c:i_b]
        np.subtract(tau[i_c:i_b], t_a, out=cruise)  # d_a + v * (tau - t_a)
        np.multiply(cruise, v, out=cruise)
        np.add(cruise, d_a, out=cruise)
    if i_b < tau.shape[0]:
        td = tau[i_b:]
        np.subtract(td, t_a, out=td)  # clip(tau - t_a - t_c, 0, t_a)
        np.subtract(td, t_c, out=td)
        np.maximum(td, 0.0, out=td)
        np.minimum(td, t_a, out=td)
        brake = dist[i_b:]
        np.multiply(td, v, out=brake)  # d_a + v * t_c + v * td - 0.5 * a * td * td, left to right
        np.add(brake, d_a + v * t_c, out=brake)
        square = np.multiply(td, half_a)
        np.multiply(square, td, out=square)
        np.subtract(brake, square, out=brake)
    np.minimum(dist, length, out=dist)  # min(dist, length) / length
    return np.divide(dist, length, out=dist)

"""The one G-code machine model: a modal interpreter (Marlin 2.1 semantics, mm) that turns commands into events.

Every reader of G-code in the toolkit steps this model: the bounds check (gcode.bounds), the
time estimate (gcode.motion), the host's deadlines (marlin.deadlines) and the simulated
printer (sim.firmware, sim.motion). Semantics, taken from Marlin (motion.cpp, G92.cpp, G28.cpp):

- Native and logical coordinates: the machine keeps the native (machine) position; a G92
  offset per axis maps it to the logical one the program speaks: logical = native + offset.
- `G90` / `G91`: absolute / relative X Y Z targets (`M82` / `M83` set the extruder's mode only;
  there is no E axis here and E words are ignored).
- `G0` / `G1`: the feed `F` (mm/min) is modal; a word X, Y or Z is a logical target (G90) or a
  logical distance from where the axis is (G91); axes without a word stay. The native target
  is clamped to the machine's limits when it has any (soft endstops). Its time is a rest-to-rest
  trapezoid at the feed and acceleration scaled so that no axis exceeds its own maximum.
- `G92 X.. Y.. Z..`: sets the logical position of the named axes without moving (the offset
  changes, the native position does not); `G92` without words is a no-op here.
- `G28 [X] [Y] [Z] [R]`: homes the named axes (all three when none is named), as G28.cpp: before
  homing X or Y, Z rises by the profile's `z_clearance_for_homing_mm` (relative while Z is not
  homed, to that height once it is, never down, never above the Z soft maximum; an R word is the
  raise instead, always relative, before a Z-only G28 too, R0 none); the native
  position of the named axes becomes the home position (Marlin's X_HOME_POS, i.e. the soft
  minimum for min endstops: the profile's `soft_min_mm`; (0, 0, 0) without a profile) and their
  G92 offset is cleared (Marlin's `set_axis_is_at_home` zeroes `position_shift`); once Z is homed
  it moves to `z_after_homing_mm` (Z_POST_CLEARANCE, down too). The Z moves run at the profile's
  `z_homing_feed_mm_s`. Without a profile there are no Z moves. The whole G28 takes
  `homing_time_s` (a whole G28 as measured, raises included) times the share of axes homed, and
  never less than its Z moves.
- `G4 P<ms> S<s>`: a dwell after the queued motion has run out; `M400`: waits for the motion.
- Before an axis is homed or moved absolutely its position is unknown (None); a relative move
  on it gives a `Move` whose `duration_s` is None (the caller bounds it).

Events are frozen values; anything else (M-codes, unparsable text) gives `Other`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from neatskin.gcode.parse import GcodeLine

Xyz = tuple[float, float, float]
MaybeXyz = tuple[float | None, float | None, float | None]
AXES = "XYZ"
_AXIS_INDEX = ((0, "X"), (1, "Y"), (2, "Z"))


class Kinematics(Protocol):
    """What the machine needs to know about a printer (a `PrinterProfile` satisfies it)."""

    @property
    def max_feed_mm_s(self) -> Iterable[float]: ...
    @property
    def max_accel_mm_s2(self) -> Iterable[float]: ...
    @property
    def soft_min_mm(self) -> Iterable[float]: ...
    @property
    def accel_mm_s2(self) -> float: ...
    @property
    def soft_max_mm(self) -> Iterable[float]: ...
    @property
    def z_clearance_for_homing_mm(self) -> float: ...
    @property
    def z_after_homing_mm(self) -> float | None: ...
    @property
    def z_homing_feed_mm_s(self) -> float: ...


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


def _rest_to_rest_s(distance_mm: float, feed_mm_s: float, accel_mm_s2: float) -> float:
    # trapezoid_time_s for v_start = v_end = 0 without the checks (the simulator's hot path), same arithmetic
    a, v = accel_mm_s2, feed_mm_s
    d_accel = v * v / (2 * a)
    if d_accel + d_accel <= distance_mm:
        return v / a + v / a + (distance_mm - d_accel - d_accel) / v
    v_peak = math.sqrt(a * distance_mm)
    return v_peak / a + v_peak / a


def limited_feed_and_accel(
    delta_mm: tuple[float, float, float], feed_mm_s: float, profile: Kinematics
) -> tuple[float, float]:
    """Nominal feed and acceleration along a move, scaled so no axis exceeds its maximum."""
    length = math.sqrt(delta_mm[0] * delta_mm[0] + delta_mm[1] * delta_mm[1] + delta_mm[2] * delta_mm[2])
    vmax, amax = _xyz(profile.max_feed_mm_s), _xyz(profile.max_accel_mm_s2)
    return _limited(delta_mm, length, feed_mm_s, profile.accel_mm_s2, vmax, amax)


def _xyz(values: Iterable[float]) -> Xyz:
    x, y, z = values
    return (float(x), float(y), float(z))


def _limited(
    delta_mm: tuple[float, float, float], length_mm: float, feed: float, accel: float, vmax: Xyz, amax: Xyz
) -> tuple[float, float]:
    if length_mm == 0:
        return feed, accel
    for d, v, a in zip(delta_mm, vmax, amax):
        if d:
            share = abs(d) / length_mm
            feed = min(feed, v / share)
            accel = min(accel, a / share)
    return feed, accel


def move_time_s(start_mm: Xyz, end_mm: Xyz, feed_mm_s: float, profile: Kinematics) -> float:
    """Time of one linear move from rest to rest at the profile's limits."""
    delta = (end_mm[0] - start_mm[0], end_mm[1] - start_mm[1], end_mm[2] - start_mm[2])
    feed, accel = limited_feed_and_accel(delta, feed_mm_s, profile)
    return trapezoid_time_s(math.sqrt(sum(d * d for d in delta)), feed, accel)


class Move(NamedTuple):
    """A G0/G1 from start_mm to end_mm (native mm; None where unknown) at the limited feed and acceleration.

    `requested_mm` is the target before clamping to the limits; `duration_s` is None when an axis
    moved relative to an unknown position. A NamedTuple, not a frozen dataclass: one is built per
    line on the simulated printer's hot path, and it builds three times faster."""

    start_mm: MaybeXyz
    end_mm: MaybeXyz
    requested_mm: MaybeXyz
    feed_mm_s: float
    accel_mm_s2: float
    length_mm: float
    duration_s: float | None

    @property
    def clamped(self) -> bool:
        return self.requested_mm != self.end_mm


def _z_moves_s(*moves: Move | None) -> float:
    """The time of a G28's Z moves (its raise before homing X or Y, its move after homing Z), those it made."""
    return sum(m.duration_s or 0.0 for m in moves if m is not None)


@dataclass(frozen=True, slots=True)
class Home:
    """A G28: the named axes (indices 0-2) go from start_mm to end_mm (native) in duration_s, the Z moves
    included: `rise` (Z up before homing X or Y) and `after` (Z to its post-homing height once Z is homed),
    each a Move at Z's homing feed or None. The homing proper runs from rise.end_mm (start_mm without a rise)
    to after.start_mm (end_mm without one) and takes `homing_s`."""

    axes: tuple[int, ...]
    start_mm: MaybeXyz
    end_mm: MaybeXyz
    duration_s: float
    rise: Move | None = None
    after: Move | None = None

    @property
    def homing_s(self) -> float:
        """The time left for the homing proper: the whole G28's, less its Z moves'."""
        return self.duration_s - _z_moves_s(self.rise, self.after)


@dataclass(frozen=True, slots=True)
class Dwell:
    """A G4: wait for the motion to run out, then `duration_s`."""

    duration_s: float


@dataclass(frozen=True, slots=True)
class Sync:
    """An M400: wait for the motion to run out."""


@dataclass(frozen=True, slots=True)
class SetPosition:
    """A G92: the logical position of some axes redefined (no motion)."""

    logical_mm: MaybeXyz


@dataclass(frozen=True, slots=True)
class Other:
    """Any other command (modes G90/G91/M82/M83 included): no motion of its own."""

    code: str


Event = Move | Home | Dwell | Sync | SetPosition | Other
SYNC = Sync()


def homing_request(params: Mapping[str, float | str]) -> tuple[tuple[int, ...], float | None]:
    """A G28's words: the axes it homes (indices; all three when it names none) and its R raise (None without one)."""
    raise_mm = params.get("R")
    axes = tuple(i for i, a in enumerate(AXES) if a in params) or (0, 1, 2)
    return axes, raise_mm if isinstance(raise_mm, float) else None


class Machine:
    """The modal state (native position, G92 offsets, G90/G91, feed) and `step(line) -> Event`.

    `profile` gives the axis limits, acceleration, home (`soft_min_mm`) and G28's Z clearances; without
    one, moves run at `accel_mm_s2` with no per-axis limits, home is (0, 0, 0) and G28 moves no Z. `homed`
    says which axes a G28 has homed (G28's Z rise depends on it). `limits_mm` (lo, hi) clamps
    native targets (soft endstops), None for no clamping. `start_mm` is the native position
    before any command (None per axis: unknown)."""

    def __init__(
        self,
        profile: Kinematics | None = None,
        *,
        start_mm: MaybeXyz = (None, None, None),
        feed_mm_s: float = 25.0,
        accel_mm_s2: float = 200.0,
        homing_time_s: float = 20.0,
        home_mm: Xyz | None = None,
        limits_mm: tuple[Xyz, Xyz] | None = None,
    ) -> None:
        self.profile = profile
        self.position_mm: list[float | None] = list(start_mm)
        self.offset_mm = [0.0, 0.0, 0.0]
        self.absolute = True
        self.extruder_absolute = True
        self.feed_mm_s = feed_mm_s
        self.homing_time_s = homing_time_s
        self.limits_mm = limits_mm
        self.homed = [False, False, False]
        if profile is not None:
            self._accel = float(profile.accel_mm_s2)
            self._vmax = _xyz(profile.max_feed_mm_s)
            self._amax = _xyz(profile.max_accel_mm_s2)
            default_home = _xyz(profile.soft_min_mm)
            self._z_max = _xyz(profile.soft_max_mm)[2]  # Z_MAX_POS: do_z_clearance goes no higher
            self._z_clearance = float(profile.z_clearance_for_homing_mm)
            after = profile.z_after_homing_mm  # Marlin without Z_AFTER_HOMING: Z_POST_CLEARANCE = the clearance
            self._z_after: float | None = self._z_clearance if after is None else float(after)
            self._z_homing_feed = float(profile.z_homing_feed_mm_s)
        else:
            self._accel = accel_mm_s2
            self._vmax = self._amax = (math.inf, math.inf, math.inf)
            default_home = (0.0, 0.0, 0.0)
            self._z_max, self._z_clearance, self._z_after, self._z_homing_feed = math.inf, 0.0, None, 1.0
        self.home_mm: Xyz = home_mm if home_mm is not None else default_home

    @property
    def logical_mm(self) -> MaybeXyz:
        p, o = self.position_mm, self.offset_mm
        return tuple(None if v is None else v + k for v, k in zip(p, o))  # type: ignore[return-value]

    def step(self, line: GcodeLine) -> Event:
        """Interpret one parsed command and return what it does."""
        code = line.code
        if code == "G1" or code == "G0":
            return self._move(line.params)
        if code == "G4":
            params = line.params
            p_ms, s_s = params.get("P"), params.get("S")
            seconds = (p_ms / 1000.0 if isinstance(p_ms, float) else 0.0) + (s_s if isinstance(s_s, float) else 0.0)
            return Dwell(seconds)
        if code == "M400":
            return SYNC
        if code == "G90" or code == "G91":
            self.absolute = code == "G90"
        elif code == "M82" or code == "M83":
            self.extruder_absolute = code == "M82"
        elif code == "G28":
            return self.home(*homing_request(line.params))
        elif code == "G92":
            return self._set_position(line.params)
        return Other(code)

    def home(self, axes: tuple[int, ...] = (0, 1, 2), raise_mm: float | None = None) -> Home:
        """G28 of `axes` as G28.cpp (see the module's docstring): the rise, the homing, the post-homing Z move.
        raise_mm: G28's R word: the raise instead of the clearance, always relative to where Z is, before any
        homing, Z's alone too (G28.cpp's seenR); R0 raises nothing."""
        position = self.position_mm
        start = (position[0], position[1], position[2])
        rise = after = None
        seen_r = raise_mm is not None
        height = self._z_clearance if raise_mm is None else raise_mm
        may_skate = seen_r or 0 in axes or 1 in axes
        if may_skate and self.profile is not None and not (seen_r and height == 0):  # do_z_clearance first
            z = position[2]
            if z is None:  # relative to an unknown height: the height stays unknown, the distance is known
                if height > 0:
                    rise = self._z_move(None, height)
            else:
                # a clearance of 0 still raises a homed Z that is below 0 to 0 (do_z_clearance(0) lowers nothing
                # but does raise: the native firmware built with Z_CLEARANCE_FOR_HOMING 0, docs/marlin.md)
                target = min(height + (0.0 if self.homed[2] and not seen_r else z), self._z_max)
                if target > z:  # never down
                    rise = self._z_move(target, target - z)
        for i in axes:
            position[i] = self.home_mm[i]
            self.offset_mm[i] = 0.0
            self.homed[i] = True
        if 2 in axes and self._z_after is not None:  # do_move_after_z_homing: Z_POST_CLEARANCE, lower allowed
            target = min(self._z_after, self._z_max)
            if target != position[2]:
                after = self._z_move(target, abs(target - position[2]))  # type: ignore[operator]
        duration = max(self.homing_time_s * len(axes) / 3, _z_moves_s(rise, after))
        end = (position[0], position[1], position[2])
        return Home(axes, start, end, duration, rise, after)

    def _z_move(self, z_mm: float | None, distance_mm: float) -> Move:
        """G28's own Z move (do_blocking_move_to_z) of `distance_mm` to native height `z_mm` (None: unknown) at
        Z's homing feed; the modes and the modal feed stay."""
        position = self.position_mm
        begin = (position[0], position[1], position[2])
        position[2] = z_mm
        end = (position[0], position[1], z_mm)
        feed, accel = _limited(
            (0.0, 0.0, distance_mm), distance_mm, self._z_homing_feed, self._accel, self._vmax, self._amax
        )
        return Move(begin, end, end, feed, accel, distance_mm, _rest_to_rest_s(distance_mm, feed, accel))

    def _set_position(self, params: dict[str, float | str]) -> SetPosition:
        logical: list[float | None] = [None, None, None]
        for i, axis in enumerate(AXES):
            value = params.get(axis)
            if isinstance(value, float):
                native = self.position_mm[i]
                if native is None:  # nothing known: take the new logical position as native
                    self.position_mm[i] = value
                    self.offset_mm[i] = 0.0
                else:
                    self.offset_mm[i] = value - native
                logical[i] = value
        return SetPosition(tuple(logical))  # type: ignore[arg-type]

    def _move(self, params: dict[str, float | str]) -> Move:
        f = params.get("F")
        if isinstance(f, float) and f > 0:
            self.feed_mm_s = f / 60.0
        start = self.position_mm
        target = start.copy()
        absolute, offset = self.absolute, self.offset_mm
        unknown = False
        for i, axis in _AXIS_INDEX:
            value = params.get(axis)
            if not isinstance(value, float):
                continue
            if absolute:
                target[i] = value - offset[i]
            else:
                here = start[i]
                if here is None:
                    unknown = True
                else:
                    target[i] = here + value
        requested = (target[0], target[1], target[2])
        if self.limits_mm is not None:
            lo, hi = self.limits_mm
            for i in range(3):
                t = target[i]
                if t is not None:
                    target[i] = lo[i] if t < lo[i] else hi[i] if t > hi[i] else t
        self.position_mm = target
        end = (target[0], target[1], target[2])
        begin = (start[0], start[1], start[2])
        if unknown or None in begin or None in end:
            if unknown or any(s is None and e is not None for s, e in zip(begin, end)):
                return Move(begin, end, requested, self.feed_mm_s, self._accel, math.nan, None)
            delta = tuple(0.0 if s is None or e is None else e - s for s, e in zip(begin, end))
        else:
            delta = (end[0] - begin[0], end[1] - begin[1], end[2] - begin[2])  # type: ignore[operator]
        length = math.sqrt(delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2])
        feed, accel = _limited(delta, length, self.feed_mm_s, self._accel, self._vmax, self._amax)  # type: ignore[arg-type]
        duration = _rest_to_rest_s(length, feed, accel) if length > 0 else 0.0
        return Move(begin, end, requested, feed, accel, length, duration)

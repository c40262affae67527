"""The dry run's probe: the simulated skin and force as the DAQ sees them along the simulated printer's trajectory.

`DryProbe` loads a press's moves (from the printer, or already on the press's own clock in the skin worker) and its
`PressConditions` (placement, depth jitter, drift, dents of earlier presses: a pure function of the press id), and
answers R_eq of every pair and the contact force at any sample times, solving the skin only where the probe may be
in it. `skin_frame` moves a point into the skin's own frame under a calibration error. The recorder
(`neatskin.sim.recorder`) samples it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neatskin.sim.depthtrace import below_runs, z_mm
from neatskin.sim.motion import positions_mm, relative_segments, segment_fraction


@dataclass(frozen=True)
class PressConditions:
    """What varies from press to press on the simulated skin, drawn from (seed, press_id) alone."""

    dx_mm: float = 0.0  # placement error
    dy_mm: float = 0.0
    depth_offset_mm: float = 0.0  # depth jitter: the probe goes this much deeper than commanded
    resistivity_factor: float | None = None  # drift of the fluid's resistivity (None = none)
    extra_factor: np.ndarray | None = None  # (channels,) residual dents of earlier presses, added to R / R0
    # R_eq of every pair before the press (dents and drift included), when computed ahead for a block of presses
    baseline_pair_resistance_ohm: np.ndarray | None = None


class DryProbe:
    """The simulated skin and force as the DAQ sees them, at the probe state the simulated printer's
    trajectory gives at each sample time (sensor frame, depth below the skin surface)."""

    def __init__(
        self,
        skin,
        calibration,
        segments_from: Callable[[float], list],
        placement_error: Callable[[int], tuple[float, float]] | None = None,
        surface_error_mm: float = 0.0,
        conditions: Callable[[int], PressConditions] | None = None,
        frame_error: tuple[float, float, float] | None = None,
    ):
        self.skin = skin
        self.surface_z_mm = calibration.surface_z_mm - surface_error_mm
        self.calibration = calibration
        self.segments_from = segments_from  # the printer's moves from the one the probe rests after at t
        self.placement_error = placement_error
        self.conditions = conditions
        # the skin's frame against the one the G-code was computed with: the printer's position is converted back
        # with the calibration the G-code used (which alone would cancel any error), then moved into the skin's
        # real frame, so the simulated skin feels where the probe really is
        self.frame_error = frame_error
        self._skin_baseline = self._baseline = np.asarray(skin.baseline_pair_resistance_ohm, dtype=float)
        self._segments: list = []
        self._offset = (0.0, 0.0)
        self._depth_offset = 0.0
        self._skin_kwargs: dict = {}
        self._printer_t0 = self._daq_t0 = 0.0

    def load(self, press_id: int, printer_t0_s: float, daq_t0_s: float, duration_s: float) -> None:
        """Take the printer's moves from t0 on for this press (the recording spans [t0, t0 + duration])."""
        self._printer_t0 = printer_t0_s
        self.load_segments(press_id, relative_segments(self.segments_from(printer_t0_s), printer_t0_s), daq_t0_s)

    @property
    def segments(self) -> list:
        """The loaded press's moves on its own clock (sim.motion.relative_segments), as `load_segments` takes them."""
        return self._segments

    def load_segments(self, press_id: int, segments: list, daq_t0_s: float) -> None:
        """Take a press's moves already on its own clock (what `segments` gave after `load`, e.g. in the skin
        worker, which has no printer), and the press's conditions."""
        self._segments, self._daq_t0 = list(segments), daq_t0_s
        self._offset = self.placement_error(press_id) if self.placement_error is not None else (0.0, 0.0)
        self._depth_offset, self._skin_kwargs, self._baseline = 0.0, {}, self._skin_baseline
        if self.conditions is not None:
            c = self.conditions(press_id)
            self._offset = (self._offset[0] + c.dx_mm, self._offset[1] + c.dy_mm)
            self._depth_offset = c.depth_offset_mm
            if c.resistivity_factor is not None:
                self._skin_kwargs["resistivity_factor"] = c.resistivity_factor
            if c.extra_factor is not None:
                self._skin_kwargs["extra_factor"] = c.extra_factor[None, :]
            if c.baseline_pair_resistance_ohm is not None:
                self._baseline = c.baseline_pair_resistance_ohm
            elif c.extra_factor is not None:
                self._baseline = self.skin.pair_resistance_ohm(0.0, 0.0, 0.0, **self._skin_kwargs)[0]
            elif c.resistivity_factor is not None:  # a uniform rho scales every R_eq by the same factor: no solve
                self._baseline = self._skin_baseline * c.resistivity_factor

    def state(self, times_s: np.ndarray) -> np.ndarray:
        """(times, 3): sensor x, y and depth below the surface (mm), rounded to 1 nm (G-code resolution is 1 um)."""
        press_t = np.asarray(times_s, dtype=float) - self._daq_t0  # the press's own clock, as its segments'
        xyz = _positions_mm(self._segments, press_t)
        sx, sy = self.calibration.to_sensor(xyz[:, 0], xyz[:, 1])
        if self.frame_error is not None:
            sx, sy = skin_frame(sx, sy, self.frame_error)
        state = np.stack(
            [
                np.asarray(sx, float) + self._offset[0],
                np.asarray(sy, float) + self._offset[1],
                self.surface_z_mm - xyz[:, 2] + self._depth_offset,
            ],
            axis=1,
        )
        return np.round(state, 6)

    def may_touch(self, times_s: np.ndarray) -> np.ndarray:
        """Indices of the times at which the probe may be in the skin: those in a move (or the rest after it)
        that reaches below the surface. Every other time is above it (depth <= 0), so its state is not needed."""
        press_t = np.asarray(times_s, dtype=float) - self._daq_t0
        segments = self._segments
        if not segments:
            return np.arange(press_t.size)
        reaches, t0s = self._reaches()
        if not reaches.any():
            return np.empty(0, dtype=np.intp)
        if press_t.size > 1 and np.any(press_t[1:] < press_t[:-1]):
            return np.flatnonzero(reaches[np.searchsorted(t0s, press_t, side="right")])
        # a sample clock: the times in force of each move are one run, [its start, the next one's start)
        edges = [0, *np.searchsorted(press_t, t0s, side="left").tolist(), press_t.size]
        runs = [np.arange(lo, hi) for lo, hi, reach in zip(edges, edges[1:], reaches) if reach and hi > lo]
        return np.concatenate(runs) if runs else np.empty(0, dtype=np.intp)

    def _reaches(self) -> tuple[np.ndarray, np.ndarray]:
        """Whether the probe may be below the surface in force of each move (index 0: before the first move, at
        its start; k: move k - 1 and the rest after it), and the moves' start times."""
        contact_z = self.surface_z_mm + self._depth_offset + _CONTACT_MARGIN_MM
        segments = self._segments
        low = [min(seg.p0_mm[2], seg.p1_mm[2]) < contact_z for seg in segments]
        return np.array([segments[0].p0_mm[2] < contact_z, *low]), np.array([seg.t0_s for seg in segments])

    def _held_xy(self) -> bool:
        """Every move that may reach into the skin is vertical, all at one (x, y), and the probe does not start
        in the skin: then every time in the skin has the same x, y (p0 + frac * 0 = p0, bit for bit)."""
        reaches, _ = self._reaches()
        if reaches[0]:
            return False
        xy = {(s.p0_mm[0], s.p0_mm[1], s.p1_mm[0], s.p1_mm[1]) for s, r in zip(self._segments, reaches[1:]) if r}
        return len(xy) == 1 and all(x0 == x1 and y0 == y1 for x0, y0, x1, y1 in xy)

    def pair_resistance_ohm(self, times_s: np.ndarray) -> np.ndarray:
        """(times, pairs) R_eq of every pair at each time: the baseline where the probe is out of the skin."""
        times_s = np.asarray(times_s, dtype=float)
        out = np.broadcast_to(self._baseline, (times_s.size, self._baseline.size)).copy()
        rows, r, inverse = self._in_skin(times_s)
        if rows.size:
            out[rows] = r[inverse]
        return out

    def slot_resistance_ohm(self, times_s: np.ndarray, pair_index: np.ndarray) -> np.ndarray:
        """(times,) R_eq of one pair per time, pair_resistance_ohm(times_s)[k, pair_index[k]] without the rest."""
        times_s = np.asarray(times_s, dtype=float)
        pair_index = np.asarray(pair_index, dtype=np.intp)
        out = self._baseline[pair_index]
        rows, r, inverse = self._in_skin(times_s)
        if rows.size:
            out[rows] = r[inverse, pair_index[rows]]
        return out

    def _in_skin(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The times the probe is in the skin (indices), R_eq of their distinct states, and each time's state."""
        near = self.may_touch(times_s)
        unique = None
        if near.size and self._segments and self._held_xy():  # a vertical press: x, y once, depths by the z axis
            z = _z_mm(self._segments, times_s[near] - self._daq_t0)
            depth = np.round(self.surface_z_mm - z + self._depth_offset, 6)  # state()'s depth column
            touching = depth > 0
            if touching.any():
                depths, inverse = np.unique(depth[touching], return_inverse=True)
                unique = np.empty((depths.size, 3))
                unique[:, :2] = self.state(times_s[near][touching][:1])[0, :2]
                unique[:, 2] = depths
        elif near.size:
            state = self.state(times_s[near])
            touching = state[:, 2] > 0
            if touching.any():
                unique, inverse = _unique_states(state[touching])
        if unique is None:
            return np.empty(0, dtype=np.intp), np.empty((0, self._baseline.size)), np.empty(0, dtype=np.intp)
        r = self.skin.pair_resistance_ohm(unique[:, 0], unique[:, 1], unique[:, 2], **self._skin_kwargs)
        return near[touching], r, inverse.reshape(-1)

    def force_n(self, times_s: np.ndarray) -> np.ndarray:
        times_s = np.asarray(times_s, dtype=float)
        force = np.zeros(times_s.size)  # above the skin the force is exactly 0 (contact_force_n of depth <= 0)
        if self._segments and times_s.ndim == 1 and not (times_s.size > 1 and np.any(times_s[1:] < times_s[:-1])):
            # a sample clock: only the runs where the probe may be below the surface (depthtrace.below_runs)
            contact_z = self.surface_z_mm + self._depth_offset + _CONTACT_MARGIN_MM
            press_t = times_s - self._daq_t0
            for lo, hi in below_runs(self._segments, press_t, contact_z):
                z = z_mm(self._segments, press_t[lo:hi])
                depth = np.maximum(np.round(self.surface_z_mm - z + self._depth_offset, 6), 0.0)
                force[lo:hi] = np.asarray(self.skin.contact_force_n(depth), dtype=float).reshape(-1)
            return force
        near = self.may_touch(times_s)
        if near.size:
            press_t = times_s[near] - self._daq_t0
            z = _z_mm(self._segments, press_t)
            depth = np.maximum(np.round(self.surface_z_mm - z + self._depth_offset, 6), 0.0)
            force[near] = np.asarray(self.skin.contact_force_n(depth), dtype=float).reshape(-1)
        return force


_CONTACT_MARGIN_MM = 1e-3  # a move that ends this close above the surface still counts as reaching it


def _positions_mm(segments: list, times_s: np.ndarray, axes: slice = slice(None)) -> np.ndarray:
    """`neatskin.sim.motion.positions_mm(segments, times_s)[:, axes]` for times in increasing order (a sample
    clock), by slices instead of masks: each move's times are one contiguous run. The same arithmetic per time
    and axis, so the same bits (tested); unordered times go to positions_mm itself."""
    times_s = np.asarray(times_s, dtype=float)
    if not segments or times_s.ndim != 1 or (times_s.size > 1 and np.any(times_s[1:] < times_s[:-1])):
        return positions_mm(segments, times_s)[:, axes]
    out = np.empty((times_s.size, len(range(3)[axes])))
    t0s = np.array([seg.t0_s for seg in segments])
    bounds = np.searchsorted(times_s, t0s, side="left")  # times before segment k's start end at bounds[k]
    out[: bounds[0]] = np.asarray(segments[0].p0_mm, float)[axes]
    stops = [*bounds[1:], times_s.size]
    for seg, lo, hi in zip(segments, bounds, stops):
        if hi <= lo:
            continue
        p0, p1 = np.asarray(seg.p0_mm, float), np.asarray(seg.p1_mm, float)
        frac = segment_fraction(seg, np.clip(times_s[lo:hi] - seg.t0_s, 0.0, None), ordered=True)
        out[lo:hi] = p0[axes] + frac[:, None] * (p1 - p0)[axes]
    return out


def _z_mm(segments: list, times_s: np.ndarray) -> np.ndarray:
    """`_positions_mm(segments, times_s, slice(2, 3))[:, 0]`: on a sample clock by neatskin.sim.depthtrace (the
    same bits, less overhead), else by positions_mm."""
    if not segments or times_s.ndim != 1 or (times_s.size > 1 and np.any(times_s[1:] < times_s[:-1])):
        return _positions_mm(segments, times_s, slice(2, 3))[:, 0]
    return z_mm(segments, times_s)


def skin_frame(x_mm, y_mm, frame_error: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Where a point of the calibrated sensor frame lies in the skin's own frame under a calibration error
    (dx, dy in mm, rotation in degrees about the sensor origin): R(rotation) (x, y) + (dx, dy)."""
    dx, dy, rotation_deg = frame_error
    theta = np.radians(rotation_deg)
    c, s = np.cos(theta), np.sin(theta)
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    return c * x - s * y + dx, s * x + c * y + dy


def _unique_states(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(states, axis=0, return_inverse=True), sorted the same way; when the probe stays at one (x, y),
    as it does through a vertical press, by the depth column alone (a 1-D sort instead of a row sort)."""
    x, y = states[:, 0], states[:, 1]
    if np.all(x == x[0]) and np.all(y == y[0]):
        depth, inverse = np.unique(states[:, 2], return_inverse=True)
        unique = np.empty((depth.size, 3))
        unique[:, 0], unique[:, 1], unique[:, 2] = x[0], y[0], depth
        return unique, inverse.reshape(-1)
    unique, inverse = np.unique(states, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)

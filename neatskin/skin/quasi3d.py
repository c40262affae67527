"""The quasi-3D pinch: the plane-strain channel kernel (a strip probe across one channel) carried onto the round
probe through two solves of the intact skin (no channel), the strip in plane strain and the round probe
axisymmetric (a real 3D solve by symmetry). Pure functions over arrays; skin/kernel.py runs the solves.

The transfer (docs/skin.md, "Mechanics: quasi-3D"). The channel's section at horizontal distance r from the round
probe's axis, at probe depth d, takes the plane-strain kernel's A/A0 at the same offset r and at the depth d* at
which the strip strains the intact host there as much as the round probe does at d:

    host_ps(r, d*) = host_ax(r, d),    A_3D(r, d) = A_ps(r, d*).

The host measure is the von Mises equivalent Hencky strain averaged over the band the channel would occupy (its
width around r, its height around its centre line; skin/hostband.py). It was chosen over the closing across the
channel's height (the measure first proposed) because near the probe's edge the closing is not monotone in depth
under either probe (it falls below 0, the layer thickening beside the probe, then rises again), so no single d*
exists there; the equivalent strain grows with depth wherever the strip's channel is still open. d* is the
shallowest depth at which the strip's host reaches the round probe's value (its running maximum over depth), so
the transfer is the identity when both hosts are the same and never opens a channel as the press deepens."""

from __future__ import annotations

import numpy as np


def band_average(line_x_mm: np.ndarray, values: np.ndarray, centres_mm, width_mm: float, axisymmetric: bool):
    """(steps, bands): `values` (steps, points) sampled along a line at `line_x_mm`, averaged over
    [c - width/2, c + width/2] for every centre c (axisymmetric: x is the radius, mirrored about the axis)."""
    fine = np.asarray(centres_mm, float)[:, None] + np.linspace(-width_mm / 2, width_mm / 2, 41)[None, :]
    x = np.abs(fine) if axisymmetric else fine
    order = np.argsort(line_x_mm)
    xs = line_x_mm[order]
    return np.stack([np.interp(x, xs, row[order]).mean(axis=1) for row in values])


def matched_depth(host_ps: np.ndarray, host_ax: np.ndarray, depths_mm: np.ndarray) -> np.ndarray:
    """(bands, depths): d* with host_ps(r, d*) = host_ax(r, d), both (depths, bands). The strip's host is taken
    as its running maximum over depth (the shallowest depth reaching a value); a value beyond the strip's largest
    maps to the deepest depth it reached, nan where the round probe's host was not solved."""
    n_d, n_b = host_ps.shape
    out = np.full((n_b, n_d), np.nan)
    for b in range(n_b):
        solved = np.flatnonzero(np.isfinite(host_ps[:, b]))
        if solved.size == 0:
            continue
        d, env = depths_mm[solved], np.maximum.accumulate(host_ps[solved, b])
        for j in range(n_d):
            target = host_ax[j, b]
            if not np.isfinite(target):
                continue
            k = int(np.searchsorted(env, target, side="left"))  # first index with env >= target
            if k == 0:
                out[b, j] = d[0]
            elif k >= env.size:
                out[b, j] = d[-1]
            else:  # env[k - 1] < target <= env[k]
                t = (target - env[k - 1]) / (env[k] - env[k - 1])
                out[b, j] = d[k] if t == 1.0 else d[k - 1] + t * (d[k] - d[k - 1])
    return out


def fill_unsolved(table: np.ndarray) -> np.ndarray:
    """(offsets, depths) with each row's depths past its deepest solved (finite) one given that value: deeper than
    the solve reached, the last solved value (the load only grows). Every row has a solved depth (depth 0)."""
    finite = np.isfinite(table)
    last = table.shape[1] - 1 - np.argmax(finite[:, ::-1], axis=1)
    beyond = np.arange(table.shape[1])[None, :] > last[:, None]
    return np.where(beyond, table[np.arange(table.shape[0]), last][:, None], table)


def area_at_depth(area_ps: np.ndarray, depths_mm: np.ndarray, d_star: np.ndarray) -> np.ndarray:
    """A_ps(r, d*) per offset row, linear in depth between the solved depths; a depth the strip's channel solve did
    not reach takes its deepest solved value (fill_unsolved, as PinchKernel does); nan d* stays nan."""
    out = np.full(d_star.shape, np.nan)
    filled = fill_unsolved(area_ps)
    for i in range(area_ps.shape[0]):
        row = filled[i]
        ok = np.isfinite(d_star[i])
        j = np.clip(np.searchsorted(depths_mm, d_star[i][ok], side="right") - 1, 0, depths_mm.size - 2)
        t = (d_star[i][ok] - depths_mm[j]) / (depths_mm[j + 1] - depths_mm[j])
        t = np.clip(t, 0.0, 1.0)
        lo, hi = row[j], row[j + 1]
        out[i, ok] = np.where(t == 0.0, lo, np.where(t == 1.0, hi, lo + t * (hi - lo)))
    return out


def transfer(area_ps: np.ndarray, host_ps: np.ndarray, host_ax: np.ndarray, depths_mm: np.ndarray):
    """(A_3D (offsets, depths), d* (offsets, depths)): the quasi-3D kernel from the plane-strain channel kernel
    `area_ps` (offsets, depths) and the two hosts' band measure (depths, offsets). A_3D is made non-decreasing in
    the offset (farther from the probe never pinches more) and then non-increasing in depth (a deeper press never
    opens a channel): the strip's own table wobbles near closure (0.34 then 0.39 at 4 mm; 0.02 under the probe
    at 1 mm against 0 at 1 to 2 mm), and the transfer carries the wobble."""
    d_star = matched_depth(host_ps, host_ax, depths_mm)
    area = area_at_depth(area_ps, depths_mm, d_star)
    return monotone(area), d_star


def monotone(area: np.ndarray) -> np.ndarray:
    """The running maximum over the offset (axis 0), then the running minimum over the depth (axis 1); nan kept.
    The second keeps the first's order: a minimum over depth of rows ordered in offset stays ordered."""
    finite = np.isfinite(area)
    up = np.fmax.accumulate(np.where(finite, area, -np.inf), axis=0)
    down = np.fmin.accumulate(np.where(finite, up, np.inf), axis=1)
    return np.where(finite, down, np.nan)


def local_spread(
    area_ps: np.ndarray,
    host_ps: np.ndarray,
    host_ax: np.ndarray,
    depths_mm: np.ndarray,
    step: int,
    d_star: np.ndarray,
) -> np.ndarray:
    """(offsets, depths): the transfer's stated uncertainty. If the strip's A/A0 were a function of the host
    measure alone, reading the strip's table at a neighbouring offset r +- step (grid steps), at the depth where
    the strip strains the host there as much as the round probe does at r, would give the same A. The spread is
    the largest difference from the transfer's own value over the two neighbours (0 at an edge of the table).
    `d_star`: the transfer's matched depths (transfer's second value), not matched again here."""
    own = area_at_depth(area_ps, depths_mm, d_star)
    spread = np.zeros_like(own)
    n = area_ps.shape[0]
    for shift in (-step, step):
        src = np.clip(np.arange(n) + shift, 0, n - 1)
        d_nb = matched_depth(host_ps[:, src], host_ax, depths_mm)
        other = area_at_depth(area_ps[src], depths_mm, d_nb)
        spread = np.fmax(spread, np.abs(other - own))
    return spread

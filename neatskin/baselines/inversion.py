"""The physics baseline: per press, (x, y, depth) by nonlinear least squares through the skin's forward model.

No training data. For every press the pair resistance changes dR (ohm) are matched by
    dR_model(x, y, depth) = R_eq(x, y, depth) - R_eq(unpressed)
from a forward model with the `pair_resistance_ohm(x_mm, y_mm, depth_mm)` signature
(`neatskin.skin.model.SkinModel`). Vectorised over presses throughout:

1. a coarse grid start: the model is evaluated once on a grid of (x, y, depth) over the skin,
   and each press starts from the few grid points nearest to it in dR space that lie apart on
   the skin (one distance matrix, in chunks), so a start in each plausible basin; a start's residual is
   its grid row's (no second model call);
2. a batched, bounded Levenberg-Marquardt (`invsolve.refine`): every (press, start) row in one array, the skin's
   analytic Jacobian from the trial step's own model call (`SkinModel.pair_resistance_and_jacobian_ohm`; a skin
   without one, or a row with a channel shut, gets forward differences: 3 model evaluations a row, only after it
   moved), per-row damping by
   the gain ratio, bounds by an active set, a secant estimate of the large residuals' curvature
   (NL2SOL), and starts of one press that meet merged; a row stops once its proposed step is under
   the tolerance (`method="reference"` is the solver before issue 27, `invref.refine_reference`, kept to
   test against; docs/baselines.md has the figures). `method="surrogate"` (`invpolish`, not the default) runs the
   same search on a cached spline table of the model and polishes each winner on the model.

Parameters are kept inside the skin's bounds and a depth range. The cost is reported like a
learned model's (fit time 0, predict time per press).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from threadpoolctl import threadpool_limits

from neatskin.baselines.invsolve import model_dr, refine

logger = logging.getLogger(__name__)


class ForwardModel(Protocol):
    """What the inversion needs from a skin: pair resistances for presses, (n,) in -> (n, pairs) out."""

    def pair_resistance_ohm(self, x_mm, y_mm, depth_mm) -> np.ndarray: ...


@dataclass(frozen=True)
class InversionResult:
    """Per press: the fitted position and depth, the final residual norm (ohm), and the run's cost."""

    xy_mm: np.ndarray  # (n, 2)
    depth_mm: np.ndarray  # (n,)
    residual_ohm: np.ndarray  # (n,) RMS over pairs of dR_model - dR
    n_iterations: int
    n_model_evaluations: int  # rows through the model; a value with its analytic Jacobian counts one
    time_s: float
    n_surrogate_evaluations: int = 0  # rows through the surrogate table (method="surrogate"), not the model


def _sqrt_threshold(limit: float) -> float:
    """The least float t with sqrt(t) >= limit (limit >= 0): for every float s >= 0, sqrt(s) < limit exactly when
    s < t, as the correctly rounded sqrt is monotone."""
    t = float(limit) * float(limit)
    while t > 0 and np.sqrt(np.nextafter(t, 0.0)) >= limit:
        t = float(np.nextafter(t, 0.0))
    while np.sqrt(t) < limit:
        t = float(np.nextafter(t, np.inf))
    return t


def model_box(skin, bounds_mm, depth_range_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unpressed skin's pair R (the dR's zero) and the search box's lower and upper (x, y, depth) corners."""
    baseline = np.asarray(skin.pair_resistance_ohm(0.0, 0.0, 0.0), dtype=float)[0]
    x0, y0, x1, y1 = bounds_mm
    lo = np.array([x0, y0, depth_range_mm[0]], dtype=float)
    hi = np.array([x1, y1, depth_range_mm[1]], dtype=float)
    return baseline, lo, hi


def _diverse_starts(
    grid_xy: np.ndarray,
    grid_dr: np.ndarray,
    dr: np.ndarray,
    k: int,
    separation_mm: float,
    chunk: int = 32,  # presses at once: a (chunk, grid rows) float64 block, 3 temporaries (19,220 rows at 0.5 mm)
    per_xy: int = 1,
) -> np.ndarray:
    """Indices (n, k): per press the grid row nearest in dR space, then the nearest at least `separation_mm`
    (in x, y) from every start already taken: starts in different basins, not k neighbours of one.

    per_xy: the grid's rows come in runs of this many with one (x, y) (the depths of one grid point): the
    distances in (x, y) are then taken once per run, the same numbers on 1 / per_xy of the work."""
    if per_xy < 1 or len(grid_xy) % per_xy or np.any(grid_xy.reshape(-1, per_xy, 2) != grid_xy[::per_xy, None]):
        per_xy = 1
    g2 = np.einsum("gp,gp->g", grid_dr, grid_dr)
    squared_separation = _sqrt_threshold(separation_mm)
    gx, gy = grid_xy[::per_xy, 0], grid_xy[::per_xy, 1]
    out = np.empty((len(dr), k), dtype=np.int64)
    for start in range(0, len(dr), chunk):
        block = dr[start : start + chunk]
        rows = np.arange(len(block))
        # up to a per-press constant; 2 x block is exact, so (2 block) @ grid' is 2 (block @ grid') bit for bit,
        # with one temporary fewer
        dist = np.matmul(2.0 * block, grid_dr.T)
        np.subtract(g2[None, :], dist, out=dist)
        dist = dist.reshape(len(block), -1, per_xy)
        # each grid point's best depth once: the rounds below exclude whole grid points, so they search the
        # (m, points) minima, not the (m, points x depths) rows. The first minimum of the flat rows is the first
        # point's first depth, so these are the same starts
        # (np.argmin over the short last axis costs ~10x these per_xy passes over strided columns; strict < keeps
        # the first minimum, as argmin does, so the same depths and distances)
        point_dist = dist[:, :, 0].copy()
        depth = np.zeros(point_dist.shape, dtype=np.int64)
        for level in range(1, per_xy):
            column = dist[:, :, level]
            lower = column < point_dist
            np.copyto(point_dist, column, where=lower)
            depth[lower] = level
        for j in range(k):
            point = np.argmin(point_dist, axis=1)
            # every point excluded (more starts than the separation leaves room for): row 0, as argmin over inf
            gone = np.isinf(point_dist[rows, point])
            out[start : start + chunk, j] = np.where(gone, 0, point * per_xy + depth[rows, point])
            if j == k - 1:
                break
            # the same sums, in the same order, as np.linalg.norm over (dx, dy), compared squared against the
            # threshold whose square root is the separation: the same starts, bit for bit
            dx = gx[None, :] - gx[point][:, None]
            dy = gy[None, :] - gy[point][:, None]
            dx *= dx
            dy *= dy
            dx += dy
            point_dist[dx < squared_separation] = np.inf
    return out


# BLAS on one thread: the start search's products are of 32-row blocks and the solver's of 3 x 3 systems, where a
# second thread only waits (on a loaded 2-core machine the start search cost ~6x the CPU on two threads: 1.5 s
# against 0.23 s on a paper dry run); the report's lanes run it on one thread anyway (tasks.py)
@threadpool_limits.wrap(limits=1, user_api="blas")
def invert_presses(
    skin: ForwardModel,
    dr_ohm: np.ndarray,
    bounds_mm: tuple[float, float, float, float],
    depth_range_mm: tuple[float, float],
    *,
    grid_step_mm: float = 1.0,
    n_grid_depths: int = 5,
    n_starts: int = 2,
    separation_mm: float = 3.0,
    max_iterations: int = 40,
    step_mm: float = 1e-3,
    tolerance_mm: float = 1e-5,
    race: tuple[int, float, float] | None = None,
    ceiling: np.ndarray | None = None,
    method: str = "batched",
) -> InversionResult:
    """(x, y, depth) per press that best explains its dR (n, pairs), starting from a coarse grid.

    bounds_mm: (x0, y0, x1, y1) the skin's extent; depth_range_mm: (low, high) depths to search.
    n_starts: each press is refined from n_starts grid points, the best in dR space and then the best
    at least separation_mm away from those taken (a channel's two sides, an edge and its mirror);
    the lowest residual wins. Every loop is capped: at most `max_iterations` steps.
    race: (steps, factor, progress) or None: after that many steps a start whose cost (sum of squares) is above
    factor times the lowest of its press's starts, or of `ceiling` (n,), a cost the press reached elsewhere, stops
    unless it is still descending (its cost under progress times its cost halfway through those steps)
    (`invsolve.drop_losers`). None (the default here, the first pass): every start runs to its end.
    method: "batched" (default) or "reference" (the pre-issue-27 loop: a Jacobian every step).
    """
    if method not in ("batched", "reference"):
        raise ValueError(f"method must be 'batched' or 'reference', got {method!r}")
    start_time = time.perf_counter()
    observed = np.asarray(dr_ohm, dtype=float)
    baseline, lo, hi = model_box(skin, bounds_mm, depth_range_mm)
    x0, y0, x1, y1 = bounds_mm
    gx = np.linspace(x0, x1, max(2, int(round((x1 - x0) / grid_step_mm)) + 1))
    gy = np.linspace(y0, y1, max(2, int(round((y1 - y0) / grid_step_mm)) + 1))
    gd = np.linspace(depth_range_mm[0], depth_range_mm[1], max(1, n_grid_depths))
    grid = np.stack(np.meshgrid(gx, gy, gd, indexing="ij"), axis=-1).reshape(-1, 3)
    grid_dr = model_dr(skin, baseline, grid)
    evaluations = len(grid)
    starts = _diverse_starts(grid[:, :2], grid_dr, observed, max(1, n_starts), separation_mm, per_xy=len(gd))
    n_start = starts.shape[1]
    p = grid[starts.T.ravel()]  # start-major: rows [j * n + i] are press i from start j
    dr = np.tile(observed, (n_start, 1))
    n = len(observed)
    if method == "reference":  # as before issue 27: the starts evaluated again
        r = model_dr(skin, baseline, p) - dr
        evaluations += len(p)
    else:  # the grid's own rows: the same model, no second call
        r = grid_dr[starts.T.ravel()] - dr
    cost = np.einsum("np,np->n", r, r)
    if method == "reference":
        from neatskin.baselines.invref import refine_reference

        cost, iteration, refine_evaluations = refine_reference(
            skin, baseline, p, r, cost, dr, lo, hi, max_iterations, step_mm, tolerance_mm, n_start
        )
    else:
        cost, iteration, refine_evaluations = refine(
            skin, baseline, p, r, cost, dr, lo, hi, max_iterations, step_mm, tolerance_mm, n_start, race, ceiling
        )
    evaluations += refine_evaluations
    best = np.argmin(cost.reshape(n_start, n), axis=0) * n + np.arange(n)
    p, cost = p[best], cost[best]
    elapsed = time.perf_counter() - start_time
    logger.debug(
        "inverted %d presses in %.2f s, %d iterations, %d model evaluations", len(p), elapsed, iteration, evaluations
    )
    return InversionResult(
        xy_mm=p[:, :2],
        depth_mm=p[:, 2],
        residual_ohm=np.sqrt(cost / max(observed.shape[1], 1)),
        n_iterations=iteration,
        n_model_evaluations=evaluations,
        time_s=elapsed,
    )


def skin_inversion(
    layout,
    dr_ohm: np.ndarray,
    fidelity: str = "deformation",
    probe_radius_mm: float = 2.75,
    margin_mm: float = 0.5,
    retry_residual_factor: float | None = 2.0,
    retry_race: tuple[int, float, float] | None = (6, 1.0, 0.9),
    deformation: str = "parametric",
    **kwargs,
) -> InversionResult:
    """invert_presses on `SkinModel(layout, fidelity, probe_radius_mm)` (the parametric pinch unless `deformation`
    says otherwise) over the layout's bounds widened by
    margin_mm (a press on an edge channel may land just outside them) and depths from 5 % to 95 %
    of the skin's thickness.

    retry_residual_factor: presses whose residual exceeds this many times the median residual (a
    local minimum, most likely) are inverted again from 6 starts 2 mm apart on a 0.5 mm grid, and
    keep the better fit. On the parametric-skin dry run of earlier versions: ~9 % of the presses, mean error
    0.39 -> 0.24 mm; on today's paper dry run (FE-kernel skin) ~38 % of the presses, mean error unchanged (the
    high residuals are the model mismatch's, not local minima). None: no second pass.
    retry_race: (steps, factor, progress) or None: in that second pass a start still above factor times the first
    fit's cost (or its press's best start's) after `steps` steps, and no longer descending (its cost above progress
    times its cost halfway), stops: a start that is behind and has stalled rarely wins. Default (6, 1.0, 0.9): on
    paper dry runs ~148 -> ~120 model evaluations a press with the same answers (docs/baselines.md); on synthetic
    presses of the model, noise-free and noisy, the full pass's fits. Without the descending exception (progress
    0) it loses true minima of noise-free presses (60 presses, seed 11: mean error 0.081 -> 0.117 mm). None: every
    start runs to its end.
    deformation: the forward model's pinch: "parametric" (default; `SkinModel`'s parametric pinch, whatever skin
    made the data) or "fe-kernel" (the packaged or cached finite-element pinch kernel of this layout and probe,
    the dry run's; never solved here: FileNotFoundError names the command that makes it). On paper dry runs the
    kernel fits lower residuals but worse positions (docs/baselines.md), so it is not the default.
    method (in kwargs): "batched" (default), "reference", or "surrogate": both passes' search on a spline table of
    the model (`invtable`, cached per skin model in the user cache) and each winner polished on the model
    (`invpolish.surrogate_inversion`, which takes its own options: polish, table_step_mm, table_depths, cache).
    On paper dry runs ~1.3x faster than "batched" with the table cached, but ~4 % of the positions move (docs/
    baselines.md, issue 27's seventh round), so it is not the default."""
    from neatskin.skin.model import DEFORMATIONS, SkinModel

    method = kwargs.pop("method", "batched")
    if method not in ("batched", "reference", "surrogate"):
        raise ValueError(f"method must be 'batched', 'reference' or 'surrogate', got {method!r}")
    if deformation not in DEFORMATIONS:
        raise ValueError(f"deformation must be one of {DEFORMATIONS}, got {deformation!r}")
    if method == "surrogate" and deformation != "parametric":
        raise ValueError(
            "method='surrogate' is measured on the parametric pinch only: with deformation='fe-kernel' it moved 81 % "
            "of a paper dry run's positions by more than 0.1 mm; use method='batched' (the default)"
        )
    dr_ohm = np.asarray(dr_ohm, dtype=float)
    if dr_ohm.ndim != 2 or not np.all(np.isfinite(dr_ohm)):
        bad = np.argwhere(~np.isfinite(np.atleast_2d(dr_ohm)))
        where = f"press {bad[0][0]}, pair column {bad[0][1]}" if len(bad) else f"shape {dr_ohm.shape}"
        raise ValueError(
            f"dr_ohm must be a finite (presses, pairs) array ({where}): a cut pair's dR is +inf in a campaign's "
            "rows; read them with neatskin.baselines.dataset.load_baseline_data, which gives each one its pair's "
            "saturation value (or drop those presses)"
        )
    kernel = None
    if deformation == "fe-kernel":
        from neatskin.skin.kernel import KernelSpec, load_kernel

        kernel = load_kernel(KernelSpec.for_layout(layout, probe_radius_mm), compute=False)
    skin = SkinModel(layout, fidelity=fidelity, probe_radius_mm=probe_radius_mm, kernel=kernel)
    depth = (0.05 * layout.thickness_mm, 0.95 * layout.thickness_mm)
    x0, y0, x1, y1 = layout.bounds_mm
    r = margin_mm
    bounds = (x0 - r, y0 - r, x1 + r, y1 + r)
    if method == "surrogate":
        from neatskin.baselines.invpolish import surrogate_inversion

        return surrogate_inversion(
            skin,
            dr_ohm,
            bounds,
            depth,
            lambda s, **kw: _two_passes(s, dr_ohm, bounds, depth, retry_residual_factor, retry_race, **kw),
            **kwargs,
        )
    return _two_passes(skin, dr_ohm, bounds, depth, retry_residual_factor, retry_race, method=method, **kwargs)


def _two_passes(skin, dr_ohm, bounds, depth, retry_residual_factor, retry_race, **kwargs) -> InversionResult:
    """skin_inversion's first pass and second pass (the presses whose residual is high, from more starts)."""
    first = invert_presses(skin, dr_ohm, bounds, depth, **kwargs)
    if retry_residual_factor is None or len(first.residual_ohm) == 0:
        return first
    suspects = np.flatnonzero(first.residual_ohm > retry_residual_factor * np.median(first.residual_ohm))
    if suspects.size == 0:
        return first
    retry_kwargs = {**kwargs, "n_starts": 6, "separation_mm": 2.0, "grid_step_mm": 0.5}
    if retry_race is not None:
        retry_kwargs["race"] = retry_race
        retry_kwargs["ceiling"] = first.residual_ohm[suspects] ** 2 * np.shape(dr_ohm)[1]
    second = invert_presses(skin, np.asarray(dr_ohm, float)[suspects], bounds, depth, **retry_kwargs)
    better = second.residual_ohm < first.residual_ohm[suspects]
    rows = suspects[better]
    xy, depth_mm, residual = first.xy_mm.copy(), first.depth_mm.copy(), first.residual_ohm.copy()
    xy[rows], depth_mm[rows], residual[rows] = (
        second.xy_mm[better],
        second.depth_mm[better],
        second.residual_ohm[better],
    )
    logger.debug("second pass on %d presses improved %d", suspects.size, rows.size)
    return InversionResult(
        xy_mm=xy,
        depth_mm=depth_mm,
        residual_ohm=residual,
        n_iterations=first.n_iterations + second.n_iterations,
        n_model_evaluations=first.n_model_evaluations + second.n_model_evaluations,
        time_s=first.time_s + second.time_s,
    )

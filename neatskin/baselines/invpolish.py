"""The inversion on a surrogate (method="surrogate", not the default): the batched multi-start search of
`skin_inversion` run on a tabulated cubic-spline stand-in of the skin model (`invtable`), then each press's winner
polished on the true model (its analytic Jacobian, with the table's Hessian for the Newton model's S).
docs/baselines.md (issue 27's seventh round) has the figures.
"""

from __future__ import annotations

import time

import numpy as np

from neatskin.baselines.invsolve import model_dr, model_drj, refine

TABLE_STEP_MM = 0.5  # x and y node spacing: the first pass's 1 mm grid and the second pass's 0.5 mm grid are nodes
TABLE_DEPTHS = 9  # the grids' 5 depths are nodes too


def surrogate_inversion(
    skin,
    dr_ohm,
    bounds_mm,
    depth_range_mm,
    two_passes,
    *,
    table_step_mm: float = TABLE_STEP_MM,
    table_depths: int = TABLE_DEPTHS,
    cache: bool = True,
    surrogate_tolerance_mm: float = 1e-4,
    polish: str = "hessian",
    max_iterations: int = 40,
    step_mm: float = 1e-3,
    tolerance_mm: float = 1e-5,
    **kwargs,
):
    """two_passes(model, **kwargs) -> InversionResult: skin_inversion's search, here on the table; then the polish on
    `skin` to tolerance_mm. polish: "hessian" (S from the table's second derivatives at every step) or "secant"
    (S from the table at the start, then NL2SOL's updates). cache: keep the table in the user cache
    (`invtable.cache_dir`), keyed by the skin model, the grid and the code."""
    from neatskin.baselines.inversion import InversionResult, model_box
    from neatskin.baselines.invtable import HybridSkin, TableSkin, cache_dir, hessian, load_table

    if polish not in ("hessian", "secant"):
        raise ValueError(f"polish must be 'hessian' or 'secant', got {polish!r}")
    started = time.perf_counter()
    observed = np.asarray(dr_ohm, dtype=float)
    baseline, lo, hi = model_box(skin, bounds_mm, depth_range_mm)
    table = load_table(skin, baseline, lo, hi, table_step_mm, table_depths, cache_dir() if cache else None)
    surrogate = TableSkin(table, baseline)
    model = HybridSkin(skin, table) if polish == "hessian" else skin
    found = two_passes(
        surrogate, max_iterations=max_iterations, step_mm=step_mm, tolerance_mm=surrogate_tolerance_mm, **kwargs
    )
    p = np.c_[found.xy_mm, found.depth_mm]
    if getattr(skin, "has_analytic_jacobian", False):
        value, jac = model_drj(skin, baseline, p)
    else:  # no analytic Jacobian (network fidelity, FE kernel, ...): the polish differences it, S seeded from the table
        value, jac, model = model_dr(skin, baseline, p), None, skin
    r = value - observed
    cost = np.einsum("np,np->n", r, r)
    curvature = np.einsum("np,npab->nab", r, hessian(table.evaluate(p, 2)))
    cost, iterations, evaluations = refine(
        model,
        baseline,
        p,
        r,
        cost,
        observed,
        lo,
        hi,
        max_iterations,
        step_mm,
        tolerance_mm,
        jac0=jac,
        curvature0=curvature,
    )
    return InversionResult(
        xy_mm=p[:, :2],
        depth_mm=p[:, 2],
        residual_ohm=np.sqrt(cost / max(observed.shape[1], 1)),
        n_iterations=found.n_iterations + iterations,
        n_model_evaluations=len(p) + evaluations,
        time_s=time.perf_counter() - started,
        n_surrogate_evaluations=surrogate.rows,
    )

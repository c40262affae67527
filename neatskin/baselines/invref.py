"""The physics inversion's reference solver (invert_presses(..., method="reference")): the loop before issue 27.

Kept only to test the default solver (`inversion._refine`) against: a fresh forward-difference Jacobian
every step, accepted or not, clipped steps, damping /10 on success and x10 on failure; a row stops on an
accepted step under the tolerance or damping past 1e8.
"""

from __future__ import annotations

import numpy as np

from neatskin.baselines.invsolve import model_dr as _model_dr


def refine_reference(skin, baseline, p, r, cost, dr, lo, hi, max_iterations, step_mm, tolerance_mm, n_start=1):
    """The solver before issue 27 (method="reference"): a fresh Jacobian every iteration, accepted or not, and
    a press stops only on an accepted step under tolerance_mm or damping past 1e8. Kept to test the default
    against. Updates p, r, cost in place; returns (cost, iterations, model evaluations)."""
    evaluations = 0
    damping = np.full(len(p), 1e-3)
    active = np.ones(len(p), dtype=bool)
    iteration = 0
    for iteration in range(1, max_iterations + 1):  # noqa: B007 (the count is read after the loop)
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        pa, ra = p[idx], r[idx]
        # forward differences, stepping inward at the upper bound
        h = np.where(pa + step_mm > hi, -step_mm, step_mm)
        shifted = np.repeat(pa[None], 3, axis=0)  # (3, m, 3)
        for k in range(3):
            shifted[k, :, k] += h[:, k]
        dr_shift = _model_dr(skin, baseline, shifted.reshape(-1, 3)).reshape(3, len(idx), -1)
        jac = (dr_shift - (ra + dr[idx])[None]) / h.T[:, :, None]  # (3, m, pairs)
        jac = jac.transpose(1, 2, 0)  # (m, pairs, 3)
        jtj = np.einsum("mpa,mpb->mab", jac, jac)
        jtr = np.einsum("mpa,mp->ma", jac, ra)
        diag = np.einsum("maa->ma", jtj)
        lhs = jtj + (damping[idx, None] * (diag + 1e-12))[:, :, None] * np.eye(3)[None]
        delta = -np.linalg.solve(lhs, jtr[:, :, None])[:, :, 0]
        candidate = np.clip(pa + delta, lo, hi)
        r_new = _model_dr(skin, baseline, candidate) - dr[idx]
        evaluations += 4 * len(idx)
        cost_new = np.einsum("np,np->n", r_new, r_new)
        better = cost_new < cost[idx]
        moved = np.max(np.abs(candidate - pa), axis=1)
        good = idx[better]
        p[good], r[good], cost[good] = candidate[better], r_new[better], cost_new[better]
        damping[good] = np.maximum(damping[good] * 0.1, 1e-9)
        damping[idx[~better]] *= 10.0
        done = (better & (moved < tolerance_mm)) | (damping[idx] > 1e8)
        active[idx[done]] = False
    return cost, iteration, evaluations

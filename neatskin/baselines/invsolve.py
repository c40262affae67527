"""The physics inversion's batched solver: a bounded Levenberg-Marquardt over every (press, start) row at once.

`refine` is the default (issue 27); `invref.refine_reference` the loop before issue 27, kept to test against.
Model calls go through `model_dr` (in chunks; an infinite resistance becomes a large finite one), or `model_drj`
(the value and the skin's analytic Jacobian, where the skin has one).
"""

from __future__ import annotations

import numpy as np

BIG_OHM = 1e9  # stands in for an infinite model resistance (a channel pinched shut)
# rows per model call: the skin's quadrature of a deep press (graded panels) outgrew its reused node buffer in
# larger calls and cost about twice as much per row (measured: ~10 us a row at 256, ~20-30 us at 1,000-3,000).
# Since 2026-11-26 the quadrature batches its sides to fit the buffer (deformation._side_panels): not re-measured
MODEL_CHUNK = 256
# rows per value-and-gradient call (model_drj): its fixed part (~0.6 ms a call) weighs more, and larger calls pay
# (measured on the paper skin, 80 % of rows on the depth bound: 13.0 us a row at 256, 11.8 at 384 and 512, 13.5 at 768)
GRADIENT_CHUNK = 512
# two running starts of one press closer than this (mm, every coordinate) share a basin: the costlier stops
# (paper dry run: 17 % fewer model evaluations, every press within 1e-3 mm of the unmerged answer at no worse
# a residual; at 1e-2 mm two presses of 2,800 moved 0.33 mm to a worse residual, so not more)
MERGE_MM = 1e-3


def model_dr(skin, baseline_ohm: np.ndarray, p: np.ndarray) -> np.ndarray:
    """dR of the model at every row of p (m, 3), in calls of at most MODEL_CHUNK rows."""
    out = np.empty((len(p), baseline_ohm.size))
    for start in range(0, len(p), MODEL_CHUNK):
        q = p[start : start + MODEL_CHUNK]
        out[start : start + MODEL_CHUNK] = skin.pair_resistance_ohm(q[:, 0], q[:, 1], q[:, 2]) - baseline_ohm
    return np.where(np.isfinite(out), out, BIG_OHM)


def model_drj(skin, baseline_ohm: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`model_dr` and d(dR)/d(x, y, depth) (m, pairs, 3) from the skin's analytic Jacobian
    (`SkinModel.pair_resistance_and_jacobian_ohm`), in calls of at most GRADIENT_CHUNK rows. A row the analytic pass
    cannot give (a channel shut) takes its dR from `pair_resistance_ohm` and a NaN Jacobian (the caller differences
    it)."""
    out = np.empty((len(p), baseline_ohm.size))
    jac = np.empty((len(p), baseline_ohm.size, 3))
    for start in range(0, len(p), GRADIENT_CHUNK):
        q = p[start : start + GRADIENT_CHUNK]
        resistance, jac[start : start + GRADIENT_CHUNK] = skin.pair_resistance_and_jacobian_ohm(
            q[:, 0], q[:, 1], q[:, 2]
        )
        out[start : start + GRADIENT_CHUNK] = resistance - baseline_ohm
    lost = ~np.all(np.isfinite(out), axis=1)
    if lost.any():
        out[lost] = model_dr(skin, baseline_ohm, p[lost])
        jac[lost] = np.nan
    return np.where(np.isfinite(out), out, BIG_OHM), jac


def model_drjh(skin, baseline_ohm: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """dR (m, pairs), its Jacobian (m, pairs, 3) and Hessian (m, pairs, 3, 3) from a skin that gives all three
    (`pair_resistance_jacobian_hessian`: the surrogate, `invtable.TableSkin`), in one call."""
    resistance, jac, hess = skin.pair_resistance_jacobian_hessian(p)
    return resistance - baseline_ohm, jac, hess


def jacobian(skin, baseline, pa, model_a, step_mm, hi, columns) -> np.ndarray:
    """d(dR)/d(x, y, depth) (m, pairs, 3) by forward differences at pa, stepping inward at the upper bound;
    model_a is the model's dR at pa. columns (m, 3) bool: only those offsets are evaluated (one model call
    for all of them), the others are NaN."""
    h = np.where(pa + step_mm > hi, -step_mm, step_mm)
    shifted = np.repeat(pa[None], 3, axis=0)  # (3, m, 3)
    for k in range(3):
        shifted[k, :, k] += h[:, k]
    wanted = columns.T  # (3, m)
    dr_shift = np.full((3, len(pa), model_a.shape[1]), np.nan)
    dr_shift[wanted] = model_dr(skin, baseline, shifted[wanted])
    jac = (dr_shift - model_a[None]) / h.T[:, :, None]  # (3, m, pairs)
    return jac.transpose(1, 2, 0)


def refine(
    skin,
    baseline,
    p,
    r,
    cost,
    dr,
    lo,
    hi,
    max_iterations,
    step_mm,
    tolerance_mm,
    n_start=1,
    race=None,
    ceiling=None,
    jac0=None,
    curvature0=None,
):
    """Bounded Levenberg-Marquardt over every (press, start) row at once, with a secant estimate of the
    residual's curvature (method="batched", the default).

    All rows in one array, each with its own damping and a mask of the rows still running; per iteration one
    batched model call for the trial steps. Where the skin has an analytic Jacobian (`has_analytic_jacobian`, as
    `SkinModel` with the parametric pinch) that call gives it too, and an accepted step's Jacobian is its trial's
    (a value with its gradient costs ~1.5 a value, forward differences ~2.3 values a row: measured on the paper
    skin); otherwise one more batched call for the Jacobians of the rows that moved (forward-difference offsets). A row stops once its proposed step is under tolerance_mm (neither evaluated nor taken) or
    its damping passes 1e8. Against the solver at 513ce57 (`invref.refine_reference` is the one before it):

    - bounds by an active set, not by clipping alone: a coordinate at its bound whose gradient points out of the
      box is held there and the step is solved over the others. Clipping the full step shortens every step of a
      row whose optimum lies past a bound to a crawl along it (on the paper dry run 91 % of the rows end at the
      depth bound);
    - the model Hessian is J'J + S, S the secant estimate of sum_i r_i d2r_i (Dennis, Gay and Welsch's NL2SOL
      update, `_secant_update`): the dry run's residuals are large (the parametric model against the FE-kernel
      skin), where Gauss-Newton alone converges linearly (~19 accepted steps a row, against ~8). A step whose
      system is not positive definite is a Gauss-Newton one;
    - the damping follows the gain ratio (Nielsen's rule: x max(1/3, 1 - (2 rho - 1)^3) on success, x 2, 4, 8 ...
      on failure) instead of /10 and x10, which alternated between a rejected and an accepted step.
    race: (steps, factor, progress) or None: after `steps` steps the rows that lose and no longer descend stop
    (`drop_losers`, against ceiling too; descending: a cost under progress times the cost halfway through).
    A skin with `pair_resistance_jacobian_hessian` (the surrogate, `invtable.TableSkin`) gives every trial its
    Hessian too: S is then the exact sum_i r_i d2r_i at every accepted point, not the secant estimate.
    jac0 (n, pairs, 3): the Jacobians at p, already known (no model call for them; NaN rows are differenced);
    curvature0 (n, 3, 3): a first S (else zero: Gauss-Newton until the first secant update).
    Updates p, r, cost in place; returns (cost, iterations, model evaluations)."""
    n = len(p)
    damping = np.full(n, 1e-3)
    growth = np.full(n, 2.0)
    active = np.ones(n, dtype=bool)
    stale = np.ones(n, dtype=bool)
    jac = np.zeros((n, r.shape[1], 3))
    jtj = np.zeros((n, 3, 3))
    jtr = np.zeros((n, 3))
    curvature = np.zeros((n, 3, 3))  # S
    moved_by = np.zeros((n, 3))  # the last accepted step
    old_jtr = np.zeros((n, 3))  # J'r before it
    old_jac_new_r = np.zeros((n, 3))  # the old J' times the new r
    has_step = np.zeros(n, dtype=bool)
    use_secant = np.zeros(n, dtype=bool)  # NL2SOL's switch: the model that predicted the last step's change better
    # a coordinate held on its bound in the last step keeps its Jacobian column (a stale one: it only decides
    # whether the coordinate stays held) until the row would stop, when the whole Jacobian is fresh again
    skip = np.zeros((n, 3), dtype=bool)
    partial = np.zeros(n, dtype=bool)
    eye = np.eye(3)[None]
    # the skin's own Jacobian where it has one: every trial step's model call gives its Jacobian too, so an accepted
    # step needs no forward differences (rows it cannot give, a channel shut, are differenced)
    analytic = bool(getattr(skin, "has_analytic_jacobian", False))
    exact = hasattr(skin, "pair_resistance_jacobian_hessian")

    def take(rows, jac_rows, hess_rows=None):
        """Fresh Jacobians for `rows`: J'J, J'r and, after a step, the secant update (or the exact S)."""
        jac[rows] = jac_rows
        jtj[rows] = np.einsum("mpa,mpb->mab", jac_rows, jac_rows)
        jtr[rows] = np.einsum("mpa,mp->ma", jac_rows, r[rows])
        stale[rows] = False
        partial[rows] = skip[rows].any(axis=1)
        if hess_rows is not None:
            curvature[rows] = np.einsum("mp,mpab->mab", r[rows], hess_rows)
            use_secant[rows] = True
            return
        upd = rows[has_step[rows]]
        if upd.size:
            curvature[upd] = secant_update(
                curvature[upd], moved_by[upd], jtr[upd] - old_jtr[upd], jtr[upd] - old_jac_new_r[upd]
            )

    if curvature0 is not None:
        curvature[:] = curvature0
        use_secant[:] = True
    if jac0 is not None:
        known = np.flatnonzero(np.all(np.isfinite(jac0), axis=(1, 2)))
        take(known, jac0[known])

    evaluations = 0
    iteration = 0
    for iteration in range(1, max_iterations + 1):  # noqa: B007 (the count is read after the loop)
        if n_start > 1 and MERGE_MM > 0:
            merge_starts(p, cost, active, n_start, MERGE_MM)
        if race is not None and iteration == race[0] // 2 + 1:
            cost_halfway = cost.copy()
        if race is not None and iteration == race[0] + 1:
            drop_losers(cost, active, n_start, race[1], ceiling, descending=cost < race[2] * cost_halfway)
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        need = idx[stale[idx]]
        if need.size and exact:  # the surrogate: its Hessian too
            _, fresh, hess = model_drjh(skin, baseline, p[need])
            evaluations += len(need)
            take(need, fresh, hess)
            need = need[:0]
        if need.size and analytic:  # the starts (their values are the grid's), and nothing else but shut rows
            _, fresh = model_drj(skin, baseline, p[need])
            evaluations += len(need)
            known = np.all(np.isfinite(fresh), axis=(1, 2))
            take(need[known], fresh[known])
            need = need[~known]
        if need.size:
            columns = ~skip[need]
            fresh = jacobian(skin, baseline, p[need], r[need] + dr[need], step_mm, hi, columns)
            take(need, np.where(columns[:, None, :], fresh, jac[need]))
            evaluations += int(columns.sum())
        pa, g = p[idx], jtr[idx]
        held = ((pa <= lo) & (g > 0)) | ((pa >= hi) & (g < 0))  # at a bound, and the descent leaves the box
        free = ~held
        both_free = free[:, :, None] & free[:, None, :]
        gauss_newton = jtj[idx] * both_free
        model = gauss_newton + (curvature[idx] * use_secant[idx, None, None]) * both_free
        diag = np.einsum("maa->ma", gauss_newton)
        shift = (damping[idx, None] * (diag + 1e-12) + held)[:, :, None] * eye
        lhs = model + shift
        definite = np.linalg.eigvalsh(lhs)[:, 0] > 0
        model[~definite] = gauss_newton[~definite]
        lhs[~definite] = model[~definite] + shift[~definite]
        delta = -np.linalg.solve(lhs, (g * free)[:, :, None])[:, :, 0]
        candidate = np.clip(pa + delta, lo, hi)
        step = candidate - pa
        small = np.max(np.abs(step), axis=1) < tolerance_mm
        # a short step from the secant model may be S's doing (too much curvature): such a row drops S and
        # proposes again; only a short Gauss-Newton step stops a row (it stays where its residual is known)
        secant = definite & use_secant[idx]
        use_secant[idx[small & secant]] = False
        recheck = idx[small & ~secant & partial[idx]]  # would stop on a stale column: a whole Jacobian first
        stale[recheck], skip[recheck] = True, False
        active[idx[small & ~secant & ~partial[idx]]] = False
        keep = ~small
        idx, candidate, step, g, model = idx[keep], candidate[keep], step[keep], g[keep], model[keep]
        held = held[keep]
        curv = curvature[idx]
        if idx.size == 0:
            continue
        if exact:
            r_new, jac_new, hess_new = model_drjh(skin, baseline, candidate)
            r_new -= dr[idx]
        elif analytic:
            r_new, jac_new = model_drj(skin, baseline, candidate)
            r_new -= dr[idx]
        else:
            r_new = model_dr(skin, baseline, candidate) - dr[idx]
        evaluations += len(idx)
        cost_new = np.einsum("np,np->n", r_new, r_new)
        predicted = -2.0 * np.einsum("ma,ma->m", g, step) - np.einsum("ma,mab,mb->m", step, model, step)
        better = cost_new < cost[idx]
        good = idx[better]
        # which model, J'J or J'J + S, predicted the change better (on steps taken and refused alike)
        newton_term = np.einsum("ma,mab,mb->m", step, curv, step)
        gn_predicted = predicted + np.where(secant[keep], newton_term, 0.0)
        actual = cost[idx] - cost_new
        use_secant[idx] = np.abs(actual - (gn_predicted - newton_term)) < np.abs(actual - gn_predicted)
        moved_by[good], old_jtr[good], has_step[good] = step[better], jtr[good], True
        old_jac_new_r[good] = np.einsum("mpa,mp->ma", jac[good], r_new[better])
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.clip((cost[good] - cost_new[better]) / predicted[better], 0.0, 1.0)
        gain = np.where(np.isfinite(gain), gain, 1.0)
        p[good], r[good], cost[good] = candidate[better], r_new[better], cost_new[better]
        stale[good] = True
        if exact:
            take(good, jac_new[better], hess_new[better])
        elif analytic:  # the trial's own Jacobian, whole: nothing held over
            known = np.all(np.isfinite(jac_new[better]), axis=(1, 2))
            take(good[known], jac_new[better][known])
        else:
            skip[good] = held[better] & (np.abs(step[better]) == 0.0)
        damping[good] = np.maximum(damping[good] * np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-9)
        growth[good] = 2.0
        bad = idx[~better]
        damping[bad] *= growth[bad]
        growth[bad] *= 2.0
        active[idx[damping[idx] > 1e8]] = False
    return cost, iteration, evaluations


def drop_losers(cost, active, n_start, factor, ceiling=None, descending=None) -> None:
    """After the race's first steps: a running row whose cost is above `factor` times the lowest cost of its
    press's rows (and above `factor` times `ceiling`, a cost per press already reached elsewhere) stops, unless
    `descending` (rows,) says it is still going down fast (a start in a better basin can be behind for a while:
    on noise-free presses it descends by orders of magnitude a step, where a start in a worse basin stalls).
    Rows are start-major, [j * n + i] press i from start j."""
    n = len(cost) // n_start
    cc = cost.reshape(n_start, n)
    best = cc.min(axis=0)
    if ceiling is not None:
        best = np.minimum(best, np.asarray(ceiling, dtype=float))
    aa = active.reshape(n_start, n)  # a view: writes reach `active`
    keep = cc <= factor * best[None, :]
    if descending is not None:
        keep |= np.asarray(descending, dtype=bool).reshape(n_start, n)
    aa &= keep


def merge_starts(p, cost, active, n_start, within_mm) -> None:
    """Two running starts of one press closer than within_mm (every coordinate) are in one basin: the costlier
    stops (its cost, above the other's, never wins). Rows are start-major, [j * n + i] press i from start j."""
    n = len(p) // n_start
    pp = p.reshape(n_start, n, 3)
    cc = cost.reshape(n_start, n)
    aa = active.reshape(n_start, n)  # a view: writes reach `active`
    for j in range(n_start):
        for k in range(j + 1, n_start):
            both = aa[j] & aa[k]
            if not both.any():
                continue
            near = both & (np.max(np.abs(pp[j] - pp[k]), axis=1) < within_mm)
            drop_k = near & (cc[k] >= cc[j])
            aa[k, drop_k] = False
            aa[j, near & ~drop_k] = False


def secant_update(s_mat: np.ndarray, step: np.ndarray, dgrad: np.ndarray, dgrad_sharp: np.ndarray) -> np.ndarray:
    """NL2SOL's update of S ~ sum_i r_i d2r_i (Dennis, Gay and Welsch 1981, eq. 3.4, with their sizing), per row.

    step s = p+ - p, dgrad y = J+'r+ - J'r, dgrad_sharp y# = J+'r+ - J'r+: S+ s = y# and S+ stays symmetric,
    the change least in a norm weighted by y. Rows with s'y <= 0 (no curvature information) keep S."""
    ss = np.einsum("mab,mb->ma", s_mat, step)
    s_ss = np.einsum("ma,ma->m", step, ss)
    with np.errstate(divide="ignore", invalid="ignore"):
        size = np.abs(np.einsum("ma,ma->m", step, dgrad_sharp)) / np.abs(s_ss)
    size = np.where(np.isfinite(size), np.minimum(size, 1.0), 1.0)
    s_mat = s_mat * size[:, None, None]
    ss = ss * size[:, None]
    ys = np.einsum("ma,ma->m", dgrad, step)
    ok = ys > 1e-12 * np.linalg.norm(dgrad, axis=1) * np.linalg.norm(step, axis=1)
    ys = np.where(ok, ys, 1.0)
    w = dgrad_sharp - ss
    change = (w[:, :, None] * dgrad[:, None, :] + dgrad[:, :, None] * w[:, None, :]) / ys[:, None, None]
    change -= (np.einsum("ma,ma->m", w, step) / ys**2)[:, None, None] * dgrad[:, :, None] * dgrad[:, None, :]
    return np.where(ok[:, None, None], s_mat + change, s_mat)

"""The Cramér-Rao bound on a press's position with nuisance parameters, with one explicit rank rule: the computation
that the electronics-only bound, the bound with depth and drift and the landing-point bound (fabrication too) share.

Input: the whitened Jacobian A (n, rows, 2 + k) = d f / d(x, y, nuisance_1..k) / noise std, so that the Fisher
information is F = A^T A, and each nuisance's prior std s_j (0 = known, the column is dropped; inf = no prior; a
finite s_j appends the row e_j / s_j to A, its 1 / s_j^2 on F's diagonal). The position's information is the Schur
complement S = F_pp - F_pn F_nn^+ F_np, and the bound is sqrt(trace(S^-1)) in the Jacobian's length unit.

How it is computed, and why so. S is never formed by subtracting matrices: the position columns, each scaled to unit
norm, are projected off the span of the nuisance columns (each scaled to unit norm too, span from their SVD, projected
twice), and the residual R (rows x 2) gives S = D R^T R D (D: the position columns' norms) through R's SVD. That works
on A, not on F = A^T A, so it does not square the conditioning; the column scaling makes the rule blind to units and
to scales (a column 1e12 times another is no more singular for it). The pinv-based Schur complement it replaces
subtracted two nearly equal 2 x 2 matrices and tested the difference against its own size, so rounding left after the
cancellation passed for information: a landing-point bound of 3,482 to 56,152 mm where the bound with fewer nuisances
was infinite, and below it at 12 of 100 positions of a seed-2019 paper dry run (docs/baselines.md).

The rank rule: the position is unresolvable (+inf) when R's smaller singular value is at most RANK_TOL = sqrt(eps)
(1.5e-8), i.e. when the position information left after the nuisances, in the direction that keeps least, is below
eps = 2.2e-16 of the position columns' own information (R has unit columns: S's eigenvalues relative to its diagonal
are R's singular values squared). Below eps relative to its diagonal an eigenvalue of F is not held by F's float64
entries at all, so no method that works through the Fisher information can tell it from 0. The data agree: on the
five paper dry runs (seeds 2019, 1 to 4) the positions where the probe shuts a channel have x and y columns parallel
to 1e-12 to 1.6e-9 (the finite differences' rounding, step 0.01 mm), and every other position keeps 4e-6 or more
(with every nuisance), so the rule sits in a gap of a decade below it and over two above. In mm: a position is called
unresolvable only where its bound would be at least 1 / (RANK_TOL max(|A_x|, |A_y|)); the whitened column norms of
those runs (signal over noise per mm) are 0.2 to 9e5 / mm, so that is over 76 mm anywhere, beyond the 30 mm skin, and
over 1.3e5 mm at the positions it declares unresolvable (their norms are at most 510 / mm).

Whatever the priors, adding a nuisance can only shrink the span's complement, so the bound with more nuisances is never
below the one with fewer (tests/test_fisherbound.py holds it as a property, with nearly rank-deficient Jacobians).
"""

from __future__ import annotations

import numpy as np

EPS = float(np.finfo(float).eps)
RANK_TOL = float(np.sqrt(EPS))  # the position rule above: R's smaller singular value at or below it is +inf


def resolved_share(whitened: np.ndarray, nuisance_std=None) -> np.ndarray:
    """R's singular values (n, 2), larger first: the share of the (unit-scaled) position columns left after the
    nuisances, in the best and the worst direction. The position is unresolvable where the second is <= RANK_TOL."""
    residual, _ = _residual(whitened, nuisance_std)
    return np.linalg.svd(residual, compute_uv=False) if len(residual) else np.zeros((0, 2))


def whitened_bound_mm(whitened: np.ndarray, nuisance_std=None, *, rank_tol: float = RANK_TOL) -> np.ndarray:
    """sqrt(trace(S^-1)) per position (n,) from the whitened Jacobian (n, rows, 2 + k) and the nuisances' prior std
    (k,) (0 = known, inf = no prior); +inf where the position is unresolvable (the module says the rule). Non-finite
    entries carry no information (0)."""
    residual, norms = _residual(whitened, nuisance_std)
    if len(residual) == 0:
        return np.zeros(0)
    _, share, vt = np.linalg.svd(residual, full_matrices=False)
    resolvable = share[:, 1] > rank_tol
    safe_share = np.where(resolvable[:, None], share, 1.0)
    safe_norms = np.where(resolvable[:, None], norms, 1.0)
    # (R^T R)^-1 = V diag(share^-2) V^T; S^-1 = D^-1 (R^T R)^-1 D^-1, so its diagonal is that of (R^T R)^-1 over D^2
    diagonal = np.einsum("nki,nk->ni", vt**2, 1.0 / safe_share**2) / safe_norms**2
    return np.where(resolvable, np.sqrt(diagonal.sum(axis=1)), np.inf)


def _residual(whitened: np.ndarray, nuisance_std) -> tuple[np.ndarray, np.ndarray]:
    """The unit-scaled position columns projected off the nuisances' span (n, rows + priors, 2), and the position
    columns' norms (n, 2)."""
    jac = np.asarray(whitened, float)
    if jac.ndim != 3 or jac.shape[2] < 2:
        raise ValueError(f"the Jacobian must be (positions, rows, 2 + nuisances), got shape {jac.shape}")
    jac = np.where(np.isfinite(jac), jac, 0.0)
    n, rows, k = jac.shape[0], jac.shape[1], jac.shape[2] - 2
    priors = np.zeros(k) if nuisance_std is None else np.asarray(nuisance_std, float).reshape(k)
    if np.any(~(priors >= 0)):  # also refuses NaN
        raise ValueError(f"nuisance priors must be >= 0 (0 = known, inf = no prior), got {priors}")
    kept = [j for j in range(k) if priors[j] > 0]
    with_prior = [j for j in kept if np.isfinite(priors[j])]
    prior_rows = np.zeros((n, len(with_prior), len(kept)))
    for r, j in enumerate(with_prior):
        prior_rows[:, r, kept.index(j)] = 1.0 / priors[j]
    position = np.concatenate([jac[..., :2], np.zeros((n, len(with_prior), 2))], axis=1)
    norms = np.linalg.norm(position, axis=1)
    unit = position / np.where(norms > 0, norms, 1.0)[:, None, :]
    if kept and n:
        nuisance = np.concatenate([jac[..., [2 + j for j in kept]], prior_rows], axis=1)
        scale = np.linalg.norm(nuisance, axis=1)
        nuisance = nuisance / np.where(scale > 0, scale, 1.0)[:, None, :]
        basis, values, _ = np.linalg.svd(nuisance, full_matrices=False)
        # the span's numerical rank as numpy's matrix_rank counts it: a nuisance combination no pair sees (to
        # rounding) costs nothing, as the pseudo-inverse had it; with a finite prior every column has its own row
        rank = values > values[:, :1] * EPS * max(rows + len(with_prior), len(kept))
        basis = basis * rank[:, None, :]
        for _ in range(2):  # projected twice: once leaves the residual off the span by ~eps of the column only
            unit = unit - basis @ (np.swapaxes(basis, 1, 2) @ unit)
    return unit, norms

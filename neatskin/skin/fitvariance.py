"""Step 4 of `skin fit`: noise and placement error from the repeats' variance, with jackknife errors and bootstrap-t.

A position's repeats scatter by the reading noise and by the placement error along the local
slope: to first order var(dR) = noise^2 + s_p^2 |d dR / d(x, y)|^2 per pair. A non-negative
linear fit across positions and pairs gives both variances; their standard errors are the
leave-one-position-out jackknife's, their quantiles those of a parametric bootstrap by position.
Intervals are returned for the variances (value, low, high); `fit` maps them through the square root.
"""

from __future__ import annotations

import numpy as np

BOOTSTRAP_REPLICATES = 400  # the noise and placement intervals' simulated campaigns
BOOTSTRAP_SEED = 2024  # fixed: one campaign always gets the same intervals
# readings of simulated campaigns fitted at once (16 MB an array): the 40 x 6-press campaigns of tests/test_skin_fit
# take 312 at a time, a 2,800-press paper campaign 26, so memory stays tens of MB whatever the campaign
BATCH_VALUES = 2**21

VarianceInterval = tuple[float, float, float]  # a variance, and its 95 % interval's low and high ends


def sum_by_cluster(cluster: np.ndarray, values: np.ndarray, n_clusters: int) -> np.ndarray:
    """Rows of `values` (n, m) summed per cluster index (n,) -> (n_clusters, m)."""
    return np.stack([np.bincount(cluster, values[:, k], n_clusters) for k in range(values.shape[1])], axis=1)


def _jackknife_covariance(design: np.ndarray, target: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """The leave-one-cluster-out jackknife covariance of the linear least-squares fit design @ coef = target:
    (C - 1) / C sum_c (coef_-c - mean)(coef_-c - mean)^T over the C clusters (an index per row) that hold rows;
    +inf with fewer than 2 clusters (MacKinnon and White 1985's jackknife, by cluster: CR3)."""
    clusters, cluster = np.unique(cluster, return_inverse=True)
    n_clusters = len(clusters)
    m = design.shape[1]
    per_ata = sum_by_cluster(cluster, (design[:, :, None] * design[:, None, :]).reshape(-1, m * m), n_clusters)
    per_ata = per_ata.reshape(n_clusters, m, m)
    per_atb = sum_by_cluster(cluster, design * target[:, None], n_clusters)
    ata, atb = per_ata.sum(axis=0), per_atb.sum(axis=0)
    if n_clusters < 2:
        return np.full((design.shape[1], design.shape[1]), np.inf)
    left_out = np.einsum("cij,cj->ci", np.linalg.pinv(ata[None] - per_ata), atb[None] - per_atb)
    deviation = left_out - left_out.mean(axis=0)
    return (n_clusters - 1) / n_clusters * (deviation.T @ deviation)


def _variance_rows(var: np.ndarray, grad2: np.ndarray, repeats: np.ndarray) -> tuple[np.ndarray, ...]:
    """The variance regression's rows, one per (repeated position, pair): design [1, |J|^2], target, position."""
    design = np.column_stack([np.ones(var[repeats].size), grad2[repeats].ravel()])
    target = var[repeats].ravel()
    position = np.repeat(np.flatnonzero(repeats), var.shape[1])
    keep = np.isfinite(design[:, 1]) & np.isfinite(target)
    return design[keep], target[keep], position[keep]


def _repeat_variance(dr: np.ndarray, inverse: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Each position's sample variance of dR over its repeats, (positions, pairs)."""
    mean = sum_by_cluster(inverse, dr, len(counts)) / counts[:, None]
    spread = sum_by_cluster(inverse, (dr - mean[inverse]) ** 2, len(counts))
    return spread / np.maximum(counts - 1, 1)[:, None]


def _variance_fit(design: np.ndarray, target: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(noise^2, s_p^2) by non-negative least squares, and their jackknife standard errors by position."""
    from scipy.optimize import nnls

    coef, _ = nnls(design, target)
    return coef, np.sqrt(np.diag(_jackknife_covariance(design, target, position)))


def _variance_fits(
    sims: np.ndarray, inverse: np.ndarray, counts: np.ndarray, grad2: np.ndarray, repeats: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """`_variance_fit` of each simulated campaign sims[b] (presses, pairs), as one per campaign gives it, bit for bit:
    the sums per position over all campaigns at once (each slot's rows added in row order, as one campaign's are),
    and the jackknife's leave-one-position-out inverses once, for the regression's design does not depend on the
    draws (only its target does); the non-negative fit and the 2 x 2 products per campaign. A campaign whose
    variances are not all finite, or fewer than 2 positions, takes the one-campaign path."""
    from scipy.optimize import nnls

    n_sims = sims.shape[0]

    def by_cluster(cluster: np.ndarray, values: np.ndarray, n_clusters: int) -> np.ndarray:  # (sims, rows, m)
        m = values.shape[2]
        slots = ((np.arange(n_sims)[:, None] * n_clusters + cluster[None, :])[:, :, None] * m + np.arange(m)).ravel()
        return np.bincount(slots, values.ravel(), n_sims * n_clusters * m).reshape(n_sims, n_clusters, m)

    mean = by_cluster(inverse, sims, len(counts)) / counts[:, None]
    var = by_cluster(inverse, (sims - mean[:, inverse]) ** 2, len(counts)) / np.maximum(counts - 1, 1)[:, None]
    design, _, position = _variance_rows(var[0], grad2, repeats)
    targets = var[:, repeats].reshape(n_sims, -1)
    clusters, cluster = np.unique(position, return_inverse=True)
    keep = np.isfinite(grad2[repeats].ravel())
    if not np.all(np.isfinite(targets)) or len(clusters) < 2:
        return [_variance_fit(*_variance_rows(v, grad2, repeats)) for v in var]
    targets = targets[:, keep]
    n_clusters, m = len(clusters), design.shape[1]
    per_ata = sum_by_cluster(cluster, (design[:, :, None] * design[:, None, :]).reshape(-1, m * m), n_clusters)
    per_ata = per_ata.reshape(n_clusters, m, m)
    left_out_inverse = np.linalg.pinv(per_ata.sum(axis=0)[None] - per_ata)
    per_atb = by_cluster(cluster, design[None] * targets[:, :, None], n_clusters)
    left_out = np.einsum("cij,bcj->bci", left_out_inverse, per_atb.sum(axis=1)[:, None] - per_atb)
    fits = []
    for b in range(n_sims):
        deviation = left_out[b] - left_out[b].mean(axis=0)
        covariance = (n_clusters - 1) / n_clusters * (deviation.T @ deviation)
        fits.append((nnls(design, targets[b])[0], np.sqrt(np.diag(covariance))))
    return fits


def placement_point(dr: np.ndarray, inverse: np.ndarray, counts: np.ndarray, slope: np.ndarray) -> float:
    """The placement error's point estimate alone (the variance regression, no bootstrap), mm."""
    from scipy.optimize import nnls

    design, target, _ = _variance_rows(_repeat_variance(dr, inverse, counts), np.nansum(slope**2, axis=-1), counts >= 2)
    return float(np.sqrt(nnls(design, target)[0][1]))


def placement_and_noise(
    dr: np.ndarray, inverse: np.ndarray, counts: np.ndarray, slope: np.ndarray
) -> tuple[VarianceInterval, VarianceInterval]:
    """noise^2 and s_p^2 from the repeats' variance, noise^2 + s_p^2 |J|^2, each with its bootstrap-t interval.

    The standard errors are the jackknife's by position; the quantiles are not Student's but those of
    the studentised error (estimate* - estimate) / se* over `BOOTSTRAP_REPLICATES` campaigns simulated
    from the fit, position by position (every press displaced by N(0, s_p^2) along the local slope
    `slope` (positions, pairs, 2), every dR with N(0, noise^2)). A few positions on the steepest
    slopes carry most of the placement, so its standard error is itself noisy and low when the
    estimate is low; Student's quantiles then cover 87 % (docs/skin.md). The intervals are formed
    for the variances (the caller maps them through the square root)."""
    from scipy.special import stdtrit

    repeats = counts >= 2
    grad2 = np.nansum(slope**2, axis=-1)
    design, target, position = _variance_rows(_repeat_variance(dr, inverse, counts), grad2, repeats)
    coef, se = _variance_fit(design, target, position)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    repeated = repeats[inverse]
    press_position = inverse[repeated]
    local = np.nan_to_num(slope[press_position])  # (repeated presses, pairs, 2)
    noise_sd, placement_sd = np.sqrt(coef)
    studentised = np.full((BOOTSTRAP_REPLICATES, 2), np.nan)
    sim_counts = np.maximum(np.bincount(press_position, minlength=len(counts)), 1)
    fits: list[tuple[np.ndarray, np.ndarray]] = []
    chunk = max(BATCH_VALUES // max(local.shape[0] * local.shape[1], 1), 1)  # campaigns fitted at once
    while len(fits) < BOOTSTRAP_REPLICATES:
        sims = []
        for _ in range(min(chunk, BOOTSTRAP_REPLICATES - len(fits))):
            moved = rng.normal(0.0, placement_sd, (len(press_position), 2))
            sims.append(np.einsum("npk,nk->np", local, moved) + rng.normal(0.0, noise_sd, local.shape[:2]))
        fits += _variance_fits(np.stack(sims), press_position, sim_counts, grad2, repeats)
    for b, (coef_b, se_b) in enumerate(fits):
        with np.errstate(divide="ignore", invalid="ignore"):
            studentised[b] = np.where(se_b > 0, (coef_b - coef) / se_b, np.nan)
    student = float(stdtrit(max(len(np.unique(position)) - 1, 1), 0.975))
    fitted: list[VarianceInterval] = []
    for k in range(2):
        column = studentised[:, k][np.isfinite(studentised[:, k])]
        if coef[k] <= 0 or len(column) < max(BOOTSTRAP_REPLICATES // 2, 1):
            # at the bound 0 the fit simulates no such spread, so nothing to studentise: Student's t
            low_q, high_q = -student, student
        else:
            low_q, high_q = np.quantile(column, [0.025, 0.975])
        fitted.append((float(coef[k]), float(coef[k] - high_q * se[k]), float(coef[k] - low_q * se[k])))
    return fitted[0], fitted[1]

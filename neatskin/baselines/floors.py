"""Floors that say what they measure: the label-noise floor (Bayes error against commanded positions) per split,
and the landing-point bound (Cramér-Rao bound of the measurement with nuisances), as pure functions.

The labels hold where the probe was commanded; the press lands at commanded + e, e ~ N(0, s^2 I) per axis
(the scene's placement error). Even an estimator that knew the landing point l exactly could only guess the
commanded c from l and the prior over c. That prior is what a split gives:
- new positions (the grouped split): c is a fresh draw of the protocol's position strategy, so the prior is that
  distribution (here a large reference sample of it, drawn with another seed);
- the split by row: every test position also has training rows, so the prior is the campaign's own positions,
  equally weighted.
The Bayes estimator under squared error is the posterior mean (its RMS error is the RMS floor); under Euclidean
error it is the posterior's spatial median (its mean error is the mean floor, found by Weiszfeld iterations). Both
are Monte Carlo over `draws` landing points per commanded position, from a fixed seed. The measurement's own
noise only adds to the error, so these are floors for any model, biased or not, that sees one press.

The landing-point bound is apart from the labels: sqrt(trace(S^-1)) of the Fisher information of one press's 28
dR about where it landed, with depth, drift and fabrication (log channel heights) as nuisance parameters with
priors (Schur complement S), for unbiased estimators of the landing point; +inf where the pairs cannot resolve the
landing point once the nuisances are accounted for (`neatskin.skin.fisherbound` has the computation and its rank rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from neatskin.skin.fisherbound import whitened_bound_mm

LABEL_FLOOR_DRAWS = 64  # landing points per commanded position: the pooled floor's MC error is ~ s / sqrt(draws n)
WEISZFELD_STEPS = 12
NEIGHBOURS = 1024  # prior points per landing point (the nearest): a 5,000-draw paper prior reaches 5.7 s at 1.35 mm
CHUNK_ROWS = 1024  # landing points evaluated at once: memory = CHUNK_ROWS x NEIGHBOURS x 2 floats
WEIGHT_CUTOFF = 1e-12  # a prior point whose posterior weight is below this share of the nearest one's is left out
SPLIT_PRIOR = {"grouped": "new_positions", "random": "by_row", "design": "by_row"}


@dataclass(frozen=True)
class LabelFloor:
    """Per commanded position (n,): the Bayes mean and RMS error (mm) against the commanded position."""

    mean_mm: np.ndarray
    rms_mm: np.ndarray

    def pooled(self) -> tuple[float, float]:
        """(mean error, RMS error) over all presses, every position weighted alike."""
        return float(np.mean(self.mean_mm)), float(np.sqrt(np.mean(self.rms_mm**2)))


def label_noise_floor(
    commanded_xy_mm: np.ndarray,
    prior_xy_mm: np.ndarray,
    placement_std_mm: float,
    *,
    draws: int = LABEL_FLOOR_DRAWS,
    seed: int = 0,
) -> LabelFloor:
    """The Bayes error per commanded position when the landing point is known and the label is the commanded one.

    commanded_xy_mm: (n, 2) positions pressed; prior_xy_mm: (m, 2) equally weighted points of the prior over the
    commanded position; placement_std_mm: per axis. Zero placement error gives exactly 0 (the label is the
    landing point)."""
    commanded = np.asarray(commanded_xy_mm, float).reshape(-1, 2)
    prior = np.asarray(prior_xy_mm, float).reshape(-1, 2)
    if not (placement_std_mm >= 0 and np.isfinite(placement_std_mm)):
        raise ValueError(f"placement_std_mm must be finite and >= 0, got {placement_std_mm!r}")
    if placement_std_mm == 0 or len(commanded) == 0:
        zero = np.zeros(len(commanded))
        return LabelFloor(zero, zero.copy())
    if len(prior) == 0:
        raise ValueError("the prior needs at least one position")
    rng = np.random.default_rng([seed, 23])
    landed = commanded[:, None, :] + placement_std_mm * rng.standard_normal((len(commanded), draws, 2))
    truth = np.repeat(commanded, draws, axis=0)
    flat = landed.reshape(-1, 2)
    sq = np.empty(len(flat))
    eu = np.empty(len(flat))
    tree = cKDTree(prior)
    weight_span_mm2 = -2.0 * math.log(WEIGHT_CUTOFF) * placement_std_mm**2 if WEIGHT_CUTOFF > 0 else math.inf
    k = min(NEIGHBOURS, len(prior))
    for start in range(0, len(flat), CHUNK_ROWS):
        part = slice(start, start + CHUNK_ROWS)
        dist, idx = tree.query(flat[part], k=k)
        dist, idx = np.asarray(dist).reshape(-1, k), np.asarray(idx).reshape(-1, k)
        # the neighbours (sorted by distance) past where every row's weight has fallen below WEIGHT_CUTOFF of its
        # nearest point's are left out: the floors move by less than 1e-12 relative (tests/test_floors.py)
        reach = np.count_nonzero(dist**2 - dist[:, :1] ** 2 < weight_span_mm2, axis=1)
        near = prior[idx[:, : int(reach.max())]]
        mean_xy, median_xy = _posterior_estimates(flat[part], near, placement_std_mm)
        sq[part] = np.sum((mean_xy - truth[part]) ** 2, axis=1)
        eu[part] = np.linalg.norm(median_xy - truth[part], axis=1)
    return LabelFloor(eu.reshape(-1, draws).mean(axis=1), np.sqrt(sq.reshape(-1, draws).mean(axis=1)))


def _posterior_estimates(landed: np.ndarray, near: np.ndarray, std_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and spatial median of the commanded position for each landing point (k, 2), over its
    nearest prior points near (k, K, 2)."""
    nx, ny = near[..., 0], near[..., 1]
    log_w = -0.5 * ((nx - landed[:, :1]) ** 2 + (ny - landed[:, 1:]) ** 2) / std_mm**2
    w = np.exp(log_w - log_w.max(axis=1, keepdims=True))
    w /= w.sum(axis=1, keepdims=True)
    mx, my = (w * nx).sum(axis=1), (w * ny).sum(axis=1)
    median_x, median_y = mx.copy(), my.copy()
    for _ in range(WEISZFELD_STEPS):  # Weiszfeld: the weighted geometric median, started at the mean
        inv = w / np.maximum(np.sqrt((nx - median_x[:, None]) ** 2 + (ny - median_y[:, None]) ** 2), 1e-9)
        total = inv.sum(axis=1)
        median_x, median_y = (inv * nx).sum(axis=1) / total, (inv * ny).sum(axis=1) / total
    return np.column_stack([mx, my]), np.column_stack([median_x, median_y])


def landing_point_bound_mm(jacobian: np.ndarray, noise_std_ohm, nuisance_std: np.ndarray | None = None) -> np.ndarray:
    """sqrt(trace(S^-1)) per position (n,), mm: the Cramér-Rao bound on where a press landed.

    jacobian: (n, pairs, 2 + k), d dR / d(x, y, nuisance_1..k); nuisance_std: (k,) prior std of each nuisance
    (0 = known, the column is dropped; inf = no prior). Non-finite Jacobian entries carry no information; a
    position the pairs cannot resolve once the nuisances are accounted for gives +inf, by the rank rule the
    electronics-only and the depth-and-drift bounds share (`neatskin.skin.fisherbound`)."""
    jac = np.asarray(jacobian, float)
    k = jac.shape[2] - 2
    priors = np.zeros(k) if nuisance_std is None else np.asarray(nuisance_std, float).reshape(k)
    if np.any(~(priors >= 0)):
        raise ValueError(f"nuisance priors must be >= 0 (0 = known, inf = no prior), got {priors}")
    std = np.broadcast_to(np.asarray(noise_std_ohm, float), jac.shape[:2])
    if not np.all(np.isfinite(std) & (std > 0)):
        raise ValueError("noise_std_ohm must be finite and > 0 for every pair")
    return whitened_bound_mm(jac / std[..., None], priors)


def split_floor_column(split: str, stat: str) -> str:
    """The physical_limit.parquet column of a split's label-noise floor ("mean" or "rms")."""
    return f"label_floor_{SPLIT_PRIOR.get(split, 'by_row')}_{stat}_mm"

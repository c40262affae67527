"""Errors in variables for `skin fit`: the per-position mean dR under a placement error N(0, s^2) per axis, as the
forward model averaged over the landing points (Gauss-Hermite quadrature), and the coverage each interval was
measured to have (benchmarks/bench_fit_coverage.py; docs/skin.md's table).

A position's presses land about its commanded point; their mean dR is E[f(c + e)], not f(c). For a nonlinear f
the two differ by about s^2 / 2 times f's curvature, which biased the pinch (0.69 to 0.73 for 0.80 at 1.35 mm).
The fit models it: the pinch is fitted to the averaged model, s is profiled from the repeats' variance, twice.
"""

from __future__ import annotations

import numpy as np

QUADRATURE_NODES = 5  # per axis: 25 landing points per position; exact for polynomials of degree 9 in each axis
PROFILE_ROUNDS = 2  # pinch at s = 0, then s from the variance, then the pinch at s, twice

# Measured coverage of the nominal 95 % intervals where it falls below the binomial(100, 0.95) band (87..100, a
# 1-in-1,000 chance each side): benchmarks/bench_fit_coverage.py, 100 seeds per placement error (0, 0.6, 1.35 mm),
# 40 positions x 8 presses, pinch 0.8 / 0.5, paper-like drift; docs/skin.md has the whole table. A parameter and
# placement not listed held 87 or more of 100 (channels: 1,142 or more of 1,200; drift: 92 or more).
MEASURED_COVERAGE: dict[str, dict[float, float]] = {
    "pinch_gain": {0.0: 0.97, 0.6: 0.93, 1.35: 0.22},
    "decay_ratio": {0.0: 0.94, 0.6: 0.89, 1.35: 0.61},
    "noise_ohm": {0.0: 0.91, 0.6: 0.82, 1.35: 0.14},
    "placement_error_mm": {0.0: 1.00, 0.6: 0.87, 1.35: 0.43},
}
SHORTFALL = 0.87  # below this share of 100 a nominal 95 % interval is out of reach: it states its coverage


def landing_offsets(sigma_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(offsets (k, 2) mm, weights (k,)) of a 2-D Gauss-Hermite rule for N(0, sigma^2 I); one node at 0 when
    sigma is 0."""
    if sigma_mm <= 0:
        return np.zeros((1, 2)), np.ones(1)
    z, w = np.polynomial.hermite_e.hermegauss(QUADRATURE_NODES)
    w = w / w.sum()
    gx, gy = np.meshgrid(z, z)
    return sigma_mm * np.column_stack([gx.ravel(), gy.ravel()]), np.outer(w, w).ravel()


def averaged_dr(skin, x_mm: np.ndarray, y_mm: np.ndarray, depth_mm: np.ndarray, sigma_mm: float) -> np.ndarray:
    """E over the landing point of the pair dR at each commanded (x, y), (positions, pairs); inf where any landing
    point cuts a pair off."""
    offsets, weights = landing_offsets(sigma_mm)
    k, n = len(weights), len(x_mm)
    xs = (np.asarray(x_mm, float)[None, :] + offsets[:, :1]).ravel()
    ys = (np.asarray(y_mm, float)[None, :] + offsets[:, 1:]).ravel()
    ds = np.tile(np.asarray(depth_mm, float), k)
    dr = np.asarray(skin.pair_resistance_ohm(xs, ys, ds), float) - skin.baseline_pair_resistance_ohm
    return np.einsum("k,knp->np", weights, dr.reshape(k, n, -1))


def coverage_of(parameter: str, placement_mm: float) -> float | None:
    """The measured coverage of a parameter's nominal 95 % interval at the nearest measured placement error, when it
    falls short of the binomial band (None otherwise: the interval holds its 95 %)."""
    table = MEASURED_COVERAGE.get(parameter)
    if not table:
        return None
    nearest = min(table, key=lambda s: abs(s - placement_mm))
    return table[nearest] if table[nearest] < SHORTFALL else None

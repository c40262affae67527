"""Position-error metrics: Euclidean error, MSE in both conventions, hits within the probe radius, Fig. 9 ellipses.

Conventions, stated once:
- `mse_mm2` is the mean over predictions of the squared Euclidean error dx^2 + dy^2.
- `mse_per_coordinate_mm2` is MATLAB's `mse` (perform) on a 2 x n target: the mean over
  every coordinate of every prediction, i.e. exactly half of `mse_mm2` for 2-D positions.
  The paper's 3.32 mm^2 most likely uses this one (MATLAB's default performance function).
- `failure_share` is the share of predictions more than `FAILURE_RADII` probe radii off.

Over repeated (seed, split) evaluations, `interval95` gives mean, std (ddof 1) and the
95 % Student-t interval of the mean of any per-repeat figure; `summarise_repeats` applies it
to every field of `PositionErrors`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PROBE_RADIUS_MM = 2.75
FAILURE_RADII = 3.0
REPEAT_FIELDS = (
    "mean_error_mm",
    "median_error_mm",
    "rms_error_mm",
    "mse_mm2",
    "mse_per_coordinate_mm2",
    "within_probe_share",
    "failure_share",
    "max_error_mm",
)


@dataclass(frozen=True)
class PositionErrors:
    """Summary of predicted versus true positions (mm)."""

    n: int
    mean_error_mm: float
    std_error_mm: float
    median_error_mm: float
    mse_mm2: float
    mse_per_coordinate_mm2: float
    within_probe_share: float
    failure_share: float = 0.0  # more than FAILURE_RADII probe radii off
    max_error_mm: float = 0.0

    @property
    def rms_error_mm(self) -> float:
        return float(np.sqrt(self.mse_mm2))


def euclidean_error_mm(y_true_mm: np.ndarray, y_pred_mm: np.ndarray) -> np.ndarray:
    """Per-prediction Euclidean distance (n,) between (n, 2) true and predicted positions."""
    diff = np.asarray(y_pred_mm, float) - np.asarray(y_true_mm, float)
    return np.sqrt(np.sum(diff * diff, axis=1))


def position_errors(
    y_true_mm: np.ndarray, y_pred_mm: np.ndarray, probe_radius_mm: float = PROBE_RADIUS_MM
) -> PositionErrors:
    """Mean and (population) std of the Euclidean error, both MSEs, and the share within the probe radius."""
    y_true_mm = np.asarray(y_true_mm, float)
    err = euclidean_error_mm(y_true_mm, y_pred_mm)
    sq = err * err
    return PositionErrors(
        n=int(err.size),
        mean_error_mm=float(err.mean()),
        std_error_mm=float(err.std()),
        median_error_mm=float(np.median(err)),
        mse_mm2=float(sq.mean()),
        mse_per_coordinate_mm2=float(sq.sum() / (err.size * y_true_mm.shape[1])),
        within_probe_share=float(np.mean(err <= probe_radius_mm)),
        failure_share=float(np.mean(err > FAILURE_RADII * probe_radius_mm)),
        max_error_mm=float(err.max()),
    )


@dataclass(frozen=True)
class Interval:
    """A figure over repeats: its mean, std (ddof 1), the 95 % t-interval of the mean, and n."""

    mean: float
    std: float
    low: float
    high: float
    n: int


def interval95(values: np.ndarray) -> Interval:
    """Mean, sample std and 95 % Student-t interval of the mean (one value: std 0, interval the value)."""
    from scipy.stats import t as student_t

    v = np.asarray(values, dtype=float).ravel()
    n = v.size
    mean = float(v.mean())
    if n < 2:
        return Interval(mean, 0.0, mean, mean, n)
    std = float(v.std(ddof=1))
    half = float(student_t.ppf(0.975, n - 1)) * std / np.sqrt(n)
    return Interval(mean, std, mean - half, mean + half, n)


def summarise_repeats(per_repeat: list[PositionErrors]) -> dict[str, Interval]:
    """Every REPEAT_FIELDS figure over the repeats, as an Interval."""
    return {name: interval95(np.array([getattr(e, name) for e in per_repeat], dtype=float)) for name in REPEAT_FIELDS}


@dataclass(frozen=True)
class ErrorEllipses:
    """Per-position mean prediction and the principal axes of the predictions (paper Fig. 9)."""

    group: np.ndarray  # (g,) group labels (position ids)
    true_mm: np.ndarray  # (g, 2)
    mean_pred_mm: np.ndarray  # (g, 2)
    std_axes_mm: np.ndarray  # (g, 2) standard deviation along each principal axis, major first
    angle_rad: np.ndarray  # (g,) direction of the major axis from +x
    n: np.ndarray  # (g,) predictions per position

    @property
    def centre_error_mm(self) -> np.ndarray:
        return euclidean_error_mm(self.true_mm, self.mean_pred_mm)


def error_ellipses(y_true_mm: np.ndarray, y_pred_mm: np.ndarray, groups: np.ndarray) -> ErrorEllipses:
    """Mean prediction per group and the std along the principal axes of its predictions' covariance.

    Covariance is the population one (divide by n) so a single prediction gives a zero ellipse.
    """
    y_true_mm, y_pred_mm = np.asarray(y_true_mm, float), np.asarray(y_pred_mm, float)
    labels, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    g = len(labels)
    mean_true = np.zeros((g, 2))
    mean_pred = np.zeros((g, 2))
    np.add.at(mean_true, inverse, y_true_mm)
    np.add.at(mean_pred, inverse, y_pred_mm)
    mean_true /= counts[:, None]
    mean_pred /= counts[:, None]
    centred = y_pred_mm - mean_pred[inverse]
    cov = np.zeros((g, 2, 2))
    np.add.at(cov, inverse, centred[:, :, None] * centred[:, None, :])
    cov /= counts[:, None, None]
    values, vectors = np.linalg.eigh(cov)  # ascending
    values = np.clip(values[:, ::-1], 0.0, None)
    major = vectors[:, :, 1]
    return ErrorEllipses(
        group=labels,
        true_mm=mean_true,
        mean_pred_mm=mean_pred,
        std_axes_mm=np.sqrt(values),
        angle_rad=np.arctan2(major[:, 1], major[:, 0]),
        n=counts,
    )

"""The Cramér-Rao bound of a press's position with the press depth as a nuisance parameter, the per-pair noise it
assumes, and the D- and A-optimality criteria the electrode optimiser ranks placements by.

Fisher information of theta = (x_mm, y_mm, depth_mm) from independent Gaussian pair noise:
F = sum_pairs j j^T / sigma^2 (3 x 3 per press). Depth unknown: the position block of F^-1 is the inverse of
the Schur complement F_pp - F_pd F_dd^-1 F_dp, so the bound with depth as nuisance is
sqrt(trace((F_pp - F_pd F_dd^-1 F_dp)^-1)), never below the known-depth bound sqrt(trace(F_pp^-1)).
A singular information (no pair sees some direction of motion) gives +inf, never NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CRITERIA = ("D", "A")
_SINGULAR = 1e-12
RELATIVE_RIDGE = 1e-8


@dataclass(frozen=True)
class PairNoise:
    """Standard deviation of one pair's measured resistance (ohm) under the study's noise model.

    model "fixed": std_ohm for every pair. model "lockin": the lock-in estimate of the simulated DAQ
    (docs/acquisition.md): sigma_R = R sqrt(2 / live_samples * (sigma_v^2 / (R I)^2 + sigma_i^2 / I^2)),
    with sigma^2 the white noise plus the ADC's lsb^2 / 12, averaged over sweeps_per_press sweeps. R is the
    pair's unpressed resistance; the baseline the change is taken against is assumed known exactly.
    """

    model: str = "lockin"
    std_ohm: float = 1.0
    voltage_noise_v: float = 2e-3
    current_noise_a: float = 1e-7
    voltage_lsb_v: float = 0.0
    current_lsb_a: float = 0.0
    amplitude_a: float = 0.002
    live_samples: int = 100
    sweeps_per_press: int = 1

    def std(self, resistance_ohm: np.ndarray) -> np.ndarray:
        r = np.asarray(resistance_ohm, float)
        if self.model == "fixed":
            return np.full(r.shape, self.std_ohm)
        var_v = self.voltage_noise_v**2 + self.voltage_lsb_v**2 / 12.0
        var_i = self.current_noise_a**2 + self.current_lsb_a**2 / 12.0
        amp = self.amplitude_a
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_var = 2.0 / self.live_samples * (var_v / (r * amp) ** 2 + var_i / amp**2)
            std = r * np.sqrt(rel_var) / math.sqrt(self.sweeps_per_press)
        return std


def fisher(jacobian: np.ndarray, std_ohm: np.ndarray) -> np.ndarray:
    """(presses, pairs, 3) Jacobian and (pairs,) or (presses, pairs) std -> (presses, 3, 3) information."""
    w = jacobian / np.asarray(std_ohm, float)[..., None]
    w = np.where(np.isfinite(w), w, 0.0)
    return np.einsum("npa,npb->nab", w, w)


def position_information(info: np.ndarray, depth_known: bool = False) -> np.ndarray:
    """(..., 3, 3) -> (..., 2, 2): the position block, or with depth unknown its Schur complement."""
    pp = info[..., :2, :2]
    if depth_known:
        return pp
    pd = info[..., :2, 2]
    dd = info[..., 2, 2]
    safe = np.where(dd > 0, dd, 1.0)
    correction = pd[..., :, None] * pd[..., None, :] / safe[..., None, None]
    return pp - np.where((dd > 0)[..., None, None], correction, 0.0)


def bound_mm(info2: np.ndarray) -> np.ndarray:
    """sqrt(trace(F^-1)) of (..., 2, 2) information, +inf where F is singular."""
    a, b, d = info2[..., 0, 0], info2[..., 0, 1], info2[..., 1, 1]
    det = a * d - b * b
    singular = det <= _SINGULAR * np.maximum(a * d, np.finfo(float).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        trace_inv = np.where(singular, np.inf, (a + d) / np.where(singular, 1.0, det))
    return np.sqrt(trace_inv)


def criterion(info2: np.ndarray, kind: str, ridge: float) -> np.ndarray:
    """Placement criterion, lower is better, averaged over the press axis (-2 after the (2, 2) block):
    D: -mean log det(F + r I); A: mean trace((F + r I)^-1) (the mean squared bound, in mm^2).

    r = ridge + RELATIVE_RIDGE * trace(F) per press. The absolute ridge keeps presses no pair sees finite (so a
    greedy search can start from two electrodes); the relative one caps a press's condition number near 1e8,
    below which the rounding of F (summed in whatever order) no longer decides the score: along a channel the
    weak direction's information can be 1e-16 of the strong one's, pure rounding noise."""
    if kind not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {kind!r}")
    a0, d0 = info2[..., 0, 0], info2[..., 1, 1]
    r = ridge + RELATIVE_RIDGE * (a0 + d0)
    a, d = a0 + r, d0 + r
    b = info2[..., 0, 1]
    det = np.maximum(a * d - b * b, np.finfo(float).tiny)
    if kind == "D":
        return -np.mean(np.log(det), axis=-1)
    return np.mean((a + d) / det, axis=-1)


def summarise_mm(bound: np.ndarray) -> dict[str, float]:
    """Mean, median and 90th percentile of a bound map (inf counts as inf), and the share of finite presses."""
    finite = np.isfinite(bound)
    return {
        "bound_mean_mm": float(np.mean(bound)) if finite.all() else math.inf,
        "bound_median_mm": float(np.median(bound)),
        "bound_p90_mm": float(np.quantile(bound, 0.9)) if finite.mean() >= 0.9 else math.inf,
        "bound_finite_share": float(finite.mean()),
    }

"""The physical limit with nuisance parameters: the Cramér-Rao bound on a press's position when its depth,
the fluid's drift and the probe's placement are not known either, per position and as a map.

A press's features f (the 28 dR, ohm) depend on the position (x, y) and on nuisances: the
press depth d (mm) and the fluid's resistivity as log(rho / rho0) (drift). With measurement
noise of std sigma per pair (independent), the Fisher information over theta = (x, y, d, log rho)
is F = J^T diag(1 / sigma^2) J, J = d f / d theta (pairs x 4). A nuisance with a prior of std s
(the scene's depth jitter, the drift over a campaign) adds 1 / s^2 to its diagonal; a nuisance
known exactly (s = 0) is left out; one with no prior at all (s = inf) adds nothing. The position's
information is the Schur complement S = F_pp - F_pn F_nn^-1 F_np, and any unbiased estimate of
where the probe landed has covariance >= S^-1. Placement error of std s_p per axis moves the
landing point away from the commanded position the labels hold, so the bound on the RMS error
against the commanded position is sqrt(trace(S^-1) + 2 s_p^2). With every nuisance known and no
placement error this is the electronics-only bound (neatskin.baselines.crb, which the skin does
not import). A position the pairs cannot resolve after the nuisances gives +inf, never NaN (the rank rule of
neatskin.skin.fisherbound, which every bound of the package shares).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from neatskin.skin.fisherbound import whitened_bound_mm

PARAMETERS = ("x_mm", "y_mm", "depth_mm", "log_resistivity")


class PressModel(Protocol):
    """What the bound needs of a skin: pair resistances under a press, with a resistivity factor."""

    def pair_resistance_ohm(
        self, x_mm, y_mm, depth_mm, peak_depth_mm=None, temperature_c=None, *, resistivity_factor=None
    ) -> np.ndarray: ...

    @property
    def baseline_pair_resistance_ohm(self) -> np.ndarray: ...


def feature_jacobian(
    skin: PressModel,
    x_mm,
    y_mm,
    depth_mm,
    step_mm: float = 0.01,
    depth_step_mm: float = 0.01,
    max_resistance_ohm: float = np.inf,
) -> np.ndarray:
    """d dR / d(x, y, depth, log rho) per position, (n, pairs, 4): ohm/mm, ohm/mm, ohm/mm, ohm.

    Central differences in x, y and depth; a drift scales the pressed and the baseline resistance
    alike, so d dR / d log rho = dR. NaN where a pair is cut off (R_eq = inf), and where any point of the
    stencil is above `max_resistance_ohm` (what the DAQ can read: beyond it the reading clips, so a channel
    nearly pinched shut, whose R_eq climbs without bound, carries no graded information)."""
    x, y, depth = (np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm))
    x, y, depth = np.broadcast_arrays(x, y, depth)
    n = x.shape[0]
    xs = np.concatenate([x + step_mm, x - step_mm, x, x, x, x, x])
    ys = np.concatenate([y, y, y + step_mm, y - step_mm, y, y, y])
    ds = np.concatenate([depth, depth, depth, depth, depth + depth_step_mm, depth - depth_step_mm, depth])
    r = np.asarray(skin.pair_resistance_ohm(xs, ys, ds), float).reshape(7, n, -1)
    with np.errstate(invalid="ignore"):
        jac = np.stack(
            [
                (r[0] - r[1]) / (2 * step_mm),
                (r[2] - r[3]) / (2 * step_mm),
                (r[4] - r[5]) / (2 * depth_step_mm),
                r[6] - np.asarray(skin.baseline_pair_resistance_ohm, float)[None, :],
            ],
            axis=-1,
        )
    jac[~np.isfinite(jac)] = np.nan
    jac[np.any(r > max_resistance_ohm, axis=0)] = np.nan
    return jac


def position_bound_mm(
    jacobian: np.ndarray,
    noise_std_ohm,
    *,
    depth_std_mm: float = 0.0,
    drift_std: float = 0.0,
    placement_std_mm: float = 0.0,
) -> np.ndarray:
    """RMS position-error bound per position (n,), mm, from a (n, pairs, 4) `feature_jacobian`.

    noise_std_ohm: (pairs,) or (n, pairs), > 0. depth_std_mm / drift_std: prior std of the press
    depth (mm) and of log rho per press (0 = known, inf = no prior). placement_std_mm: per axis.
    Non-finite Jacobian rows (a pair cut off) carry no information."""
    jac = np.asarray(jacobian, float)
    if jac.ndim != 3 or jac.shape[2] != len(PARAMETERS):
        raise ValueError(f"the Jacobian must be (positions, pairs, {len(PARAMETERS)}), got shape {jac.shape}")
    std = np.broadcast_to(np.asarray(noise_std_ohm, float), jac.shape[:2])
    if not np.all(np.isfinite(std) & (std > 0)):
        raise ValueError("noise_std_ohm must be finite and > 0 for every pair (a noise-free pair has no finite bound)")
    for name, value in (
        ("depth_std_mm", depth_std_mm),
        ("drift_std", drift_std),
        ("placement_std_mm", placement_std_mm),
    ):
        if not (value >= 0):  # also refuses NaN
            raise ValueError(f"{name} must be >= 0 (0 = known exactly, inf = no prior), got {value!r}")
    priors = np.array([depth_std_mm, drift_std], float)
    # the Schur complement and its rank rule are those of every bound of the package (neatskin.skin.fisherbound)
    trace_inv = whitened_bound_mm(jac / std[..., None], priors) ** 2
    return np.sqrt(trace_inv + 2.0 * placement_std_mm**2)


def bound_map_mm(
    skin: PressModel,
    bounds_mm: tuple[float, float, float, float],
    depth_mm: float,
    noise_std_ohm,
    step_mm: float = 1.0,
    **priors: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bound on a grid over bounds_mm = (x0, y0, x1, y1): x (nx,), y (ny,), bound (ny, nx) in mm."""
    x0, y0, x1, y1 = bounds_mm
    xs = np.arange(x0, x1 + 1e-9, step_mm)
    ys = np.arange(y0, y1 + 1e-9, step_mm)
    gx, gy = np.meshgrid(xs, ys)
    jac = feature_jacobian(skin, gx.ravel(), gy.ravel(), np.full(gx.size, depth_mm))
    return xs, ys, position_bound_mm(jac, noise_std_ohm, **priors).reshape(gx.shape)

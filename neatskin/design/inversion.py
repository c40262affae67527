"""A model-based inversion error map for a candidate: each press of the map measured with the study's per-pair
Gaussian noise, then located by the skin model itself (the estimator a perfect model allows): a search over a
library of presses (a position grid x a few depths), then damped Gauss-Newton on (x, y, depth) with the adjoint
Jacobian from the few best library matches, keeping the least misfit. Vectorised over presses and noise draws.

The error is global, so unlike the local bound it counts presses whose noisy resistances lead the search to a
wrong basin. More starts, fewer of them: 1 start gives a 2.3 mm mean on the 5 x 5 boundary-8 skin, 3 starts
0.14 mm, 6 starts 0.07 mm (medians all 0.015 mm), so it is an upper estimate of what the model itself allows.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neatskin.design.bound import PairNoise
from neatskin.design.sensitivity import press_jacobian
from neatskin.layout import Layout

_CHUNK = 256
_DAMPING = 1e-9


@dataclass(frozen=True)
class InversionSpec:
    """draws: noise draws per press (the spread is over draws); library: positions per axis of the search grid;
    depth_offsets_mm: library depths, relative to the pressed depth; iterations: Gauss-Newton steps from each of
    the `starts` best library presses; the start that ends with the least misfit wins."""

    enabled: bool = False
    draws: int = 2
    library: int = 40
    depth_offsets_mm: tuple[float, ...] = (-0.5, 0.0, 0.5)
    iterations: int = 6
    starts: int = 3


def inversion_errors_mm(
    layout: Layout,
    electrodes: np.ndarray,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    depth_mm: float,
    probe_radius_mm: float,
    fidelity: str,
    noise: PairNoise,
    z: np.ndarray,
    spec: InversionSpec,
    seed: int,
    tick: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Euclidean position error (mm) of the inversion, (draws, presses); tick(press evaluations) after the
    library and after each Gauss-Newton step (the progress bar)."""
    tick = tick or (lambda _units: None)
    electrodes = np.sort(np.asarray(electrodes))  # the same set draws the same noise, whatever the numbering
    a, b = np.triu_indices(len(electrodes), 1)

    def model(x, y, d):
        pj = press_jacobian(layout, electrodes, x, y, d, probe_radius_mm, fidelity, z=z)
        return pj.pressed_pair_ohm(a, b), pj.pair_jacobian(a, b), pj.baseline_pair_ohm[a, b]

    truth, _, baseline = model(x_mm, y_mm, depth_mm)
    tick(x_mm.size * electrodes.size)
    sigma = noise.std(baseline)
    rng = np.random.default_rng([seed, 11])
    n = x_mm.size
    measured = truth[None] + sigma * rng.standard_normal((spec.draws, n, sigma.size))
    measured = measured.reshape(-1, sigma.size) / sigma  # whitened, (draws * presses, pairs)
    x0, y0, x1, y1 = layout.bounds_mm
    gx, gy = np.meshgrid(np.linspace(x0, x1, spec.library), np.linspace(y0, y1, spec.library))
    lib_d = np.repeat([depth_mm + o for o in spec.depth_offsets_mm], gx.size)
    lib_x, lib_y = np.tile(gx.ravel(), len(spec.depth_offsets_mm)), np.tile(gy.ravel(), len(spec.depth_offsets_mm))
    lib_r, _, _ = model(lib_x, lib_y, lib_d)
    tick(lib_x.size * electrodes.size)
    lib_w = np.where(np.isfinite(lib_r), lib_r / sigma, 1e12)
    lib_sq = np.einsum("lp,lp->l", lib_w, lib_w)
    k = max(1, min(spec.starts, lib_sq.size))
    best = np.empty((measured.shape[0], k), dtype=np.intp)
    for s in range(0, measured.shape[0], _CHUNK):
        distance = lib_sq[None] - 2.0 * measured[s : s + _CHUNK] @ lib_w.T
        best[s : s + _CHUNK] = np.argpartition(distance, k - 1, axis=1)[:, :k]
    start = best.ravel()  # every measurement's k best library presses, each refined
    theta = np.stack([lib_x[start], lib_y[start], lib_d[start]], axis=1)
    target = np.repeat(measured, k, axis=0)
    lo = np.array([x0, y0, 0.2])
    hi = np.array([x1, y1, layout.thickness_mm - 0.2])
    for _ in range(spec.iterations):
        r, jac, _ = model(theta[:, 0], theta[:, 1], theta[:, 2])
        resid = target - np.where(np.isfinite(r), r, 0.0) / sigma
        jw = np.where(np.isfinite(jac), jac, 0.0) / sigma[None, :, None]
        jtj = np.einsum("npa,npb->nab", jw, jw)
        jtj += (_DAMPING * np.trace(jtj, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(3)
        step = np.linalg.solve(jtj, np.einsum("npa,np->na", jw, resid)[..., None])[..., 0]
        theta = np.clip(theta + step, lo, hi)
        tick(theta.shape[0] * electrodes.size)
    r, _, _ = model(theta[:, 0], theta[:, 1], theta[:, 2])
    tick(theta.shape[0] * electrodes.size)
    misfit = np.sum((target - np.where(np.isfinite(r), r / sigma, 1e12)) ** 2, axis=1).reshape(-1, k)
    theta = theta.reshape(-1, k, 3)[np.arange(misfit.shape[0]), np.argmin(misfit, axis=1)]
    truth_xy = np.tile(np.stack([x_mm, y_mm], axis=1), (spec.draws, 1))
    return np.linalg.norm(theta[:, :2] - truth_xy, axis=1).reshape(spec.draws, n)

"""The physical limit: Cramér-Rao bound on the RMS position error from a feature Jacobian and its noise.

For features f(x, y) + noise with covariance C, any unbiased position estimate has
covariance >= F^-1 with Fisher information F = J^T C^-1 J (J = d f / d(x, y), pairs x 2).
The bound on the RMS Euclidean error is sqrt(trace(F^-1)). A position the pairs cannot resolve (no pair sees a
direction of motion, to float precision) gives +inf, never NaN: the rank rule of `neatskin.skin.fisherbound`,
which the bounds with nuisances share.
"""

from __future__ import annotations

import numpy as np

from neatskin.errors import DataError
from neatskin.skin.fisherbound import whitened_bound_mm


def fisher_information(
    jacobian: np.ndarray, noise_cov: np.ndarray | None = None, noise_std: np.ndarray | None = None
) -> np.ndarray:
    """F = J^T C^-1 J for every position: jacobian (n, pairs, 2) -> (n, 2, 2)."""
    jac = np.asarray(jacobian, dtype=float)
    if jac.ndim != 3 or jac.shape[2] != 2:
        raise DataError(
            f"the Jacobian must be (positions, pairs, 2), got shape {jac.shape}",
            field="jacobian",
            fix="stack d feature / d(x, y) per position",
        )
    if (noise_cov is None) == (noise_std is None):
        raise DataError(
            "give exactly one of noise_cov (pairs, pairs) and noise_std (pairs,)",
            field="noise",
            fix="pass the measurement noise once",
        )
    pairs = jac.shape[1]
    if noise_std is not None:
        std = np.broadcast_to(np.asarray(noise_std, float), (pairs,))
        if np.any(~np.isfinite(std)) or np.any(std <= 0):
            raise DataError(
                "noise_std must be finite and > 0 for every pair",
                field="noise_std",
                fix="a noise-free pair has no finite bound; give its real noise floor",
            )
        weighted = jac / std[None, :, None] ** 2
        return np.einsum("npa,npb->nab", jac, weighted)
    cov = np.asarray(noise_cov, float)
    if cov.shape != (pairs, pairs) or not np.all(np.isfinite(cov)):
        raise DataError(
            f"noise_cov must be a finite ({pairs}, {pairs}) matrix, got {cov.shape}",
            field="noise_cov",
            fix="one row and column per electrode pair",
        )
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError as exc:
        raise DataError(
            "noise_cov is not positive definite",
            field="noise_cov",
            fix="add the per-pair noise variance on the diagonal",
        ) from exc
    whitened = np.linalg.solve(chol[None], jac)  # L^-1 J, so F = (L^-1 J)^T (L^-1 J)
    return np.einsum("npa,npb->nab", whitened, whitened)


def cramer_rao_bound_mm(
    jacobian: np.ndarray, noise_cov: np.ndarray | None = None, noise_std: np.ndarray | None = None
) -> np.ndarray:
    """RMS position-error bound sqrt(trace(F^-1)) per position (n,), in the Jacobian's length unit.

    jacobian: (n, pairs, 2), d feature / d(x_mm, y_mm) in feature units per mm.
    noise_cov: (pairs, pairs) or noise_std: (pairs,), in feature units.
    Non-finite Jacobian rows (a pair cut off) count as carrying no information.
    """
    jac = np.asarray(jacobian, dtype=float)
    jac = np.where(np.isfinite(jac), jac, 0.0)
    fisher_information(jac, noise_cov, noise_std)  # validates the shapes and the noise (one clear error)
    if noise_std is not None:
        whitened = jac / np.broadcast_to(np.asarray(noise_std, float), (jac.shape[1],))[None, :, None]
    else:
        whitened = np.linalg.solve(np.linalg.cholesky(np.asarray(noise_cov, float))[None], jac)
    # no nuisance here: the rank rule is that of every bound of the package (neatskin.skin.fisherbound)
    return whitened_bound_mm(whitened)

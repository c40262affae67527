"""The paper's model as a scikit-learn estimator: a tanh network trained by Levenberg-Marquardt (trainlm style).

`LMNetworkRegressor` is a scikit-learn estimator: n_features-n_hidden-n_outputs, tanh hidden
layer, linear outputs (28-5-2 = 157 weights for the paper's skin), inputs and targets scaled
to [0, 1], trained by our own vectorised Levenberg-Marquardt loop (its numerics, pure functions
on the scaled arrays, are `lmnetwork`'s; this module scales, draws the restarts and keeps the best):

- analytic Jacobian of the residuals w.r.t. every weight, shape (n_samples * n_outputs, n_weights);
- step dw solving (J^T J + mu I) dw = -J^T e; mu x mu_dec after a step that lowers the
  training error, x mu_inc (and retry with the same Jacobian) after one that does not;
- stop after `max_fail` epochs in a row without a better validation error (the best
  validation weights are kept), when the gradient norm falls below `min_grad`, when mu
  exceeds `mu_max`, or after `max_epochs`;
- `n_restarts` restarts, each with its own Nguyen-Widrow-like initial weights and its own
  random validation subset; the restart with the lowest validation MSE wins. Given `groups`
  (position ids) in `fit`, a restart's validation rows are whole positions it does not train
  on, so on a split over positions the stop and the choice see new positions, as the test does.
- restarts run in `n_jobs` processes through joblib (its backend, e.g. Dask, is the caller's
  choice; n_jobs=None follows an enclosing `joblib.parallel_config`, else 1), one restart per
  dispatch; each restart is a pure function of its seed, so the result does not depend on n_jobs.

`fit_with_scipy_lm` solves the same least-squares problem (same scaling, same initial
weights, same training rows) with `scipy.optimize.least_squares(method="lm")`; tests and the
benchmark hold our loop to it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils import check_random_state
from sklearn.utils.validation import check_is_fitted, validate_data
from threadpoolctl import threadpool_limits

from neatskin.baselines.lmnetwork import LMRun, forward, initial_weights, residual_jacobian, train_lm

# ---------------------------------------------------------------- scaling


def minmax_fit(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column minimum and range for scaling to [0, 1]; a constant column gets range 1 (maps to 0)."""
    low = a.min(axis=0)
    span = a.max(axis=0) - low
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    return low, span


# ---------------------------------------------------------------- estimator


class LMNetworkRegressor(RegressorMixin, BaseEstimator):
    """The paper's n_features-n_hidden-n_outputs tanh network trained by Levenberg-Marquardt.

    Parameters follow MATLAB's trainlm defaults. `val_fraction` is the share of the rows
    given to `fit` held out (per restart, at random) to stop training and to pick the best
    restart; the paper's 95/3/2 split gives 3/98 of the rows that reach `fit`.

    Fitted attributes: `weights_` (flat, `n_weights_` long), `n_weights_`, `val_mse_` and
    `n_epochs_` (per restart), `best_restart_`, `stop_reasons_`, `fit_time_s_`, `n_features_in_`.
    """

    def __init__(
        self,
        n_hidden: int = 5,
        n_restarts: int = 10,
        val_fraction: float = 3 / 98,
        max_epochs: int = 1000,
        mu: float = 1e-3,
        mu_dec: float = 0.1,
        mu_inc: float = 10.0,
        mu_max: float = 1e10,
        max_fail: int = 6,
        min_grad: float = 1e-7,
        random_state=None,
        n_jobs: int | None = None,
    ):
        self.n_hidden = n_hidden
        self.n_restarts = n_restarts
        self.val_fraction = val_fraction
        self.max_epochs = max_epochs
        self.mu = mu
        self.mu_dec = mu_dec
        self.mu_inc = mu_inc
        self.mu_max = mu_max
        self.max_fail = max_fail
        self.min_grad = min_grad
        self.random_state = random_state
        self.n_jobs = n_jobs

    # evaluate.fit_predict passes the training rows' position ids to fit
    _validates_on_groups = True

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = True
        return tags

    def _check_params(self) -> None:
        if int(self.n_hidden) < 1 or int(self.n_restarts) < 1 or int(self.max_epochs) < 0:
            raise ValueError("n_hidden and n_restarts must be >= 1 and max_epochs >= 0")
        if not 0.0 <= float(self.val_fraction) < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction!r}")
        if not (self.mu > 0 and 0 < self.mu_dec < 1 < self.mu_inc and self.mu_max > self.mu):
            raise ValueError("need mu > 0, 0 < mu_dec < 1 < mu_inc and mu_max > mu")

    def fit(self, X, y, groups=None):
        """Fit n_restarts networks and keep the best on validation; groups: validate on whole positions."""
        self._check_params()
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        self.groups_ = None if groups is None else np.asarray(groups).reshape(-1)
        if self.groups_ is not None and len(self.groups_) != len(X):
            raise ValueError(f"groups has {len(self.groups_)} entries for {len(X)} rows")
        start = time.perf_counter()
        self._y_1d = y.ndim == 1
        y2 = y.reshape(len(y), -1).astype(np.float64)
        self.x_min_, self.x_span_ = minmax_fit(X)
        self.y_min_, self.y_span_ = minmax_fit(y2)
        xs = (X - self.x_min_) / self.x_span_
        ys = (y2 - self.y_min_) / self.y_span_
        n = len(xs)
        n_val = int(round(self.val_fraction * n)) if n >= 3 else 0
        n_val = min(n_val, n - 1)
        seeds = check_random_state(self.random_state).randint(0, 2**31 - 1, size=int(self.n_restarts))
        self.restart_seeds_ = seeds
        self.n_val_ = n_val
        self.n_rows_ = n
        runs = self._run_restarts(xs, ys, n_val, seeds)

        self.val_mse_ = np.array([r.val_mse for r in runs])
        self.n_epochs_ = np.array([r.n_epochs for r in runs])
        self.stop_reasons_ = [r.stop_reason for r in runs]
        self.best_restart_ = int(np.argmin(self.val_mse_))
        self.weights_ = runs[self.best_restart_].weights
        self.n_outputs_ = ys.shape[1]
        self.n_weights_ = self.weights_.size
        self.fit_time_s_ = time.perf_counter() - start
        return self

    def _run_restarts(self, xs: np.ndarray, ys: np.ndarray, n_val: int, seeds: np.ndarray) -> list[LMRun]:
        if self.n_jobs == 1 or len(seeds) == 1:
            return [self._fit_one(xs, ys, n_val, int(seed)) for seed in seeds]
        from joblib import Parallel, delayed

        # n_jobs None: joblib's default, 1 unless an enclosing `joblib.parallel_config(n_jobs=...)` says more
        # (scikit-learn's convention). One restart per dispatch: restarts differ up to 5x in epochs, and
        # batching two of them would leave a core idle at the end.
        return Parallel(n_jobs=self.n_jobs, batch_size=1)(
            delayed(self._fit_one)(xs, ys, n_val, int(seed)) for seed in seeds
        )

    def _restart_setup(self, n_rows: int, n_inputs: int, n_outputs: int, n_val: int, seed: int):
        """(train rows, val rows, initial weights) of one restart, all drawn from its seed.

        With groups: whole positions, drawn at random until they hold about n_val rows (at least
        one position, and at least one left to train on)."""
        rng = np.random.default_rng(seed)
        groups = getattr(self, "groups_", None)
        if groups is not None and n_val > 0 and len(np.unique(groups)) >= 2:
            labels, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
            order = rng.permutation(len(labels))
            n_groups = int(np.searchsorted(np.cumsum(counts[order]), n_val)) + 1
            is_val = np.isin(inverse, order[: min(n_groups, len(labels) - 1)])
            val, train = np.flatnonzero(is_val), np.flatnonzero(~is_val)
        else:
            order = rng.permutation(n_rows)
            val, train = order[:n_val], order[n_val:]
        if n_val == 0:  # too few rows to hold any out: validate on the training rows
            val = train
        return train, val, initial_weights(n_inputs, int(self.n_hidden), n_outputs, rng)

    def restart_rows(self, restart: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(train, validation) row indices, into the rows given to fit, of restart `restart`."""
        check_is_fitted(self, "weights_")
        n_rows = len(self.groups_) if self.groups_ is not None else self.n_rows_
        train, val, _ = self._restart_setup(
            n_rows, self.n_features_in_, self.n_outputs_, self.n_val_, int(self.restart_seeds_[restart])
        )
        return train, val

    def restart_problem(self, X, y, restart: int = 0) -> dict[str, np.ndarray]:
        """The scaled least-squares problem restart `restart` of the last fit solved (same X, y as fit).

        Keys x_train, y_train, x_val, y_val, w0: what `fit_with_scipy_lm` needs to solve the
        same problem from the same start.
        """
        check_is_fitted(self, "weights_")
        X = np.asarray(X, dtype=float)
        y2 = np.asarray(y, dtype=float).reshape(len(X), -1)
        xs, ys = (X - self.x_min_) / self.x_span_, (y2 - self.y_min_) / self.y_span_
        train, val, w0 = self._restart_setup(
            len(xs), xs.shape[1], ys.shape[1], self.n_val_, int(self.restart_seeds_[restart])
        )
        return {"x_train": xs[train], "y_train": ys[train], "x_val": xs[val], "y_val": ys[val], "w0": w0}

    def _fit_one(self, xs: np.ndarray, ys: np.ndarray, n_val: int, seed: int) -> LMRun:
        """One restart: its own validation rows and initial weights, both from `seed`."""
        train, val, w0 = self._restart_setup(len(xs), xs.shape[1], ys.shape[1], n_val, seed)
        return train_lm(
            w0,
            xs[train],
            ys[train],
            xs[val],
            ys[val],
            int(self.n_hidden),
            mu=self.mu,
            mu_dec=self.mu_dec,
            mu_inc=self.mu_inc,
            mu_max=self.mu_max,
            max_fail=int(self.max_fail),
            max_epochs=int(self.max_epochs),
            min_grad=self.min_grad,
        )

    def predict(self, X):
        check_is_fitted(self, "weights_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        xs = (X - self.x_min_) / self.x_span_
        _, out = forward(self.weights_, xs, int(self.n_hidden), self.n_outputs_)
        pred = out * self.y_span_ + self.y_min_
        return pred.ravel() if self._y_1d else pred


# ---------------------------------------------------------------- scipy reference


@dataclass(frozen=True)
class ScipyLMResult:
    weights: np.ndarray
    train_mse: float
    val_mse: float
    n_evaluations: int
    fit_time_s: float


def fit_with_scipy_lm(
    x_train: np.ndarray,
    y_train: np.ndarray,
    x_val: np.ndarray,
    y_val: np.ndarray,
    w0: np.ndarray,
    n_hidden: int,
    *,
    analytic_jacobian: bool = False,
    max_nfev: int | None = None,
) -> ScipyLMResult:
    """The same problem solved by `scipy.optimize.least_squares(method="lm")` (MINPACK).

    Inputs are already scaled to [0, 1]; w0 is the same start our loop uses. MINPACK runs to
    its own convergence on the training rows (it has no validation stop); the validation MSE
    is reported for comparison. With `analytic_jacobian=False` (scipy's default) MINPACK
    differentiates by finite differences, as a plain `least_squares(method="lm")` call does.
    """
    from scipy.optimize import least_squares

    n_outputs = y_train.shape[1]

    def residuals(w: np.ndarray) -> np.ndarray:
        return (forward(w, x_train, n_hidden, n_outputs)[1] - y_train).ravel()

    def jacobian(w: np.ndarray) -> np.ndarray:
        hidden, _ = forward(w, x_train, n_hidden, n_outputs)
        return residual_jacobian(w, x_train, hidden, n_outputs)

    start = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):  # same footing as train_lm
        result = least_squares(
            residuals, w0, jac=jacobian if analytic_jacobian else "2-point", method="lm", max_nfev=max_nfev
        )
    elapsed = time.perf_counter() - start
    val_err = forward(result.x, x_val, n_hidden, n_outputs)[1] - y_val
    return ScipyLMResult(
        result.x,
        float(np.mean(result.fun**2)),
        float(np.mean(val_err**2)),
        int(result.nfev),
        elapsed,
    )

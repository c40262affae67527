"""Splits and evaluation: the paper's random 95/3/2 split by row, the honest k-fold over positions, timings.

- `paper_split`: rows shuffled and cut 95 % train, 3 % validation, 2 % test, as the paper
  states (its split is by row, so repeats of a test position are also in training: the
  error it gives is optimistic for positions never pressed before).
- `grouped_folds`: k-fold over position ids (GroupKFold, shuffled): no position appears in
  both the training and the test rows of a fold; every row is predicted once, out of fold.
- `evaluate_model`: fits a fresh clone per fold, times fit and predict, pools the test
  predictions and summarises them with `position_errors`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.model_selection import GroupKFold

from neatskin.baselines.metrics import PositionErrors, position_errors
from neatskin.errors import DataError

PAPER_FRACTIONS = (0.95, 0.03, 0.02)
SPLITS = ("grouped", "random")
MIN_TRAIN_ROWS = 6


def paper_split(n_rows: int, random_state: int | None = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row indices (train, val, test) in the paper's 95/3/2 proportions (val and test rounded, >= 1 each)."""
    if n_rows < 3:
        raise DataError(
            f"{n_rows} presses cannot be split 95/3/2", field="rows", fix="record more presses (the paper used 2,800)"
        )
    order = np.random.default_rng(random_state).permutation(n_rows)
    n_test = max(1, int(round(PAPER_FRACTIONS[2] * n_rows)))
    n_val = max(1, int(round(PAPER_FRACTIONS[1] * n_rows)))
    return order[n_test + n_val :], order[n_test : n_test + n_val], order[:n_test]


def grouped_folds(
    groups: np.ndarray, n_splits: int = 5, random_state: int | None = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, test) row indices of a k-fold over groups (positions); k = min(n_splits, n_groups)."""
    n_groups = len(np.unique(groups))
    if n_groups < 2:
        raise DataError(
            f"a grouped split needs at least 2 positions, the dataset has {n_groups}",
            field="position_id",
            fix="record more positions, or use --split random",
        )
    k = min(n_splits, n_groups)
    splitter = GroupKFold(n_splits=k, shuffle=True, random_state=random_state)
    dummy = np.zeros(len(groups))
    return [(train, test) for train, test in splitter.split(dummy, dummy, groups)]


def split_folds(split: str, groups: np.ndarray, random_state: int | None = 0, n_splits: int = 5):
    """The (train, test) folds of a named split; for "random" the paper's train and val rows train."""
    if split == "grouped":
        return grouped_folds(groups, n_splits, random_state)
    if split == "random":
        train, val, test = paper_split(len(groups), random_state)
        return [(np.sort(np.concatenate([train, val])), np.sort(test))]
    raise DataError(f"unknown split {split!r}", field="split", fix="use 'grouped' or 'random'")


@dataclass(frozen=True)
class ModelResult:
    """One model on one split: pooled test errors, timings, and the predictions behind them."""

    model: str
    split: str
    errors: PositionErrors
    fit_time_s: float  # mean over folds, one fit each
    predict_time_per_sample_s: float
    n_folds: int
    n_train_rows: int  # mean over folds
    y_true_mm: np.ndarray
    y_pred_mm: np.ndarray
    groups: np.ndarray

    def row(self) -> dict:
        e = self.errors
        return {
            "model": self.model,
            "split": self.split,
            "n_test": e.n,
            "n_folds": self.n_folds,
            "mean_error_mm": e.mean_error_mm,
            "std_error_mm": e.std_error_mm,
            "median_error_mm": e.median_error_mm,
            "mse_mm2": e.mse_mm2,
            "mse_per_coordinate_mm2": e.mse_per_coordinate_mm2,
            "within_probe_pct": 100.0 * e.within_probe_share,
            "fit_time_s": self.fit_time_s,
            "predict_time_per_sample_us": 1e6 * self.predict_time_per_sample_s,
        }


def check_arrays(X: np.ndarray, y: np.ndarray, source: str = "<arrays>") -> None:
    """One DataError for non-finite features or targets, naming the first bad column index."""
    for name, a in (("features", X), ("positions", y)):
        bad = ~np.isfinite(a)
        if bad.any():
            col = int(np.argmax(bad.any(axis=0)))
            raise DataError(
                f"{int(bad.sum())} non-finite {name} (first in column {col})",
                file=source,
                field=f"{name}[:, {col}]",
                fix="drop or repair those presses before fitting",
            )


def evaluate_model(
    name: str,
    estimator: BaseEstimator,
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    split: str = "grouped",
    random_state: int | None = 0,
    n_splits: int = 5,
) -> ModelResult:
    """Fit a clone per fold, predict the held-out rows, pool them, time both."""
    check_arrays(X, y)
    folds = split_folds(split, groups, random_state, n_splits)
    pred = np.full(y.shape, np.nan)
    tested = np.zeros(len(y), dtype=bool)
    fit_s, predict_s, n_pred, n_train = 0.0, 0.0, 0, 0
    for train, test in folds:
        if len(train) < MIN_TRAIN_ROWS:
            raise DataError(
                f"only {len(train)} training presses in a fold",
                field="rows",
                fix=f"record at least {MIN_TRAIN_ROWS} presses per fold",
            )
        model = clone(estimator)
        start = time.perf_counter()
        model.fit(X[train], y[train])
        fit_s += time.perf_counter() - start
        start = time.perf_counter()
        pred[test] = model.predict(X[test])
        predict_s += time.perf_counter() - start
        tested[test] = True
        n_pred += len(test)
        n_train += len(train)
    if not np.isfinite(pred[tested]).all():
        raise DataError(
            f"model {name} predicted non-finite positions",
            field=name,
            fix="report this dataset: every baseline should give finite predictions",
        )
    return ModelResult(
        model=name,
        split=split,
        errors=position_errors(y[tested], pred[tested]),
        fit_time_s=fit_s / len(folds),
        predict_time_per_sample_s=predict_s / max(n_pred, 1),
        n_folds=len(folds),
        n_train_rows=n_train // len(folds),
        y_true_mm=y[tested],
        y_pred_mm=pred[tested],
        groups=groups[tested],
    )

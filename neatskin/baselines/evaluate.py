"""Splits and repeated evaluation: the paper's 95/3/2 by row, k-fold over positions, the 11 x 6 test design.

- `paper_split`: rows shuffled and cut 95 % train, 3 % validation, 2 % test, as the paper
  states (its split is by row, so repeats of a test position are also in training: the
  error it gives is optimistic for positions never pressed before).
- `grouped_folds`: k-fold over position ids (GroupKFold, shuffled): no position appears in
  both the training and the test rows of a fold.
- `design_split`: the paper's Fig. 9 test design: 11 positions with 6 presses each held out as
  test rows (their other presses stay in training, as in a split by row), so every test
  position has 6 predictions and its error ellipse is never degenerate.
- `repeat_splits`: n (seed, split) repeats of a split, each one fit. Grouped repeat r is fold
  r mod k of the k-fold partition seeded random_state + r // k.
- `evaluate_models`: every (model, split, repeat) fit as one task (`fit_tasks`), run in processes
  (this one among them), costliest first (`neatskin.baselines.tasks`; a joblib backend, e.g. Dask); per
  repeat the held-out errors, pooled and summarised (`collect_results`).

Anything that makes a figure weak (few test rows, folds cut) is returned as a warning text.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.model_selection import GroupKFold

from neatskin.baselines.metrics import Interval, PositionErrors, position_errors, summarise_repeats
from neatskin.baselines.tasks import Task, run_tasks
from neatskin.errors import DataError

logger = logging.getLogger(__name__)

PAPER_FRACTIONS = (0.95, 0.03, 0.02)
SPLITS = ("grouped", "random", "design")
DESIGN_POSITIONS = 11
DESIGN_PRESSES = 6
MIN_TRAIN_ROWS = 6
MIN_TEST_ROWS = 20  # below this a share moves in steps of 5 % or more per press


class BaselineWarning(UserWarning):
    """A baseline figure that stands on weak ground (few test rows, folds cut, errors beyond the skin)."""


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


def _check_folds(n_splits: int) -> None:
    if int(n_splits) < 2:
        raise DataError(
            f"--folds {n_splits}: a k-fold over positions needs k >= 2 (k = 1 leaves no position to test on)",
            field="folds",
            fix="use --folds 2 or more (5 is the default)",
        )


def grouped_folds(
    groups: np.ndarray, n_splits: int = 5, random_state: int | None = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, test) row indices of a k-fold over groups (positions); k = min(n_splits, n_groups)."""
    _check_folds(n_splits)
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


def design_split(
    groups: np.ndarray,
    random_state: int | None = 0,
    n_positions: int = DESIGN_POSITIONS,
    presses_per_position: int = DESIGN_PRESSES,
) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) rows: `presses_per_position` presses of each of `n_positions` positions are the test rows.

    Only positions with more than `presses_per_position` presses are drawn (one at least stays in
    training); with fewer such positions than asked, all of them are used.
    """
    labels, counts = np.unique(groups, return_counts=True)
    eligible = labels[counts > presses_per_position]
    if len(eligible) == 0:
        raise DataError(
            f"no position has more than {presses_per_position} presses for the {n_positions} x "
            f"{presses_per_position} test design",
            field="repeats",
            fix=f"press each position at least {presses_per_position + 1} times, or use --split grouped",
        )
    rng = np.random.default_rng(random_state)
    chosen = rng.choice(eligible, size=min(n_positions, len(eligible)), replace=False)
    test = np.concatenate(
        [rng.choice(np.flatnonzero(groups == g), presses_per_position, replace=False) for g in chosen]
    )
    test = np.sort(test)
    train = np.setdiff1d(np.arange(len(groups)), test)
    return train, test


def split_folds(split: str, groups: np.ndarray, random_state: int | None = 0, n_splits: int = 5):
    """The (train, test) folds of a named split; for "random" the paper's train and val rows train."""
    if split == "grouped":
        return grouped_folds(groups, n_splits, random_state)
    if split == "random":
        train, val, test = paper_split(len(groups), random_state)
        return [(np.sort(np.concatenate([train, val])), np.sort(test))]
    if split == "design":
        return [design_split(groups, random_state)]
    raise DataError(f"unknown split {split!r}", field="split", fix="use 'grouped', 'random' or 'design'")


@dataclass(frozen=True)
class Repeat:
    """One (seed, split) repeat: its training and test rows."""

    index: int
    seed: int
    train: np.ndarray
    test: np.ndarray


def repeat_splits(
    split: str, groups: np.ndarray, n_repeats: int = 10, random_state: int | None = 0, n_splits: int = 5
) -> tuple[list[Repeat], list[str]]:
    """n_repeats (train, test) repeats of a split, and warnings about them (folds cut, few test rows)."""
    if int(n_repeats) < 1:
        raise DataError(f"{n_repeats} repeats", field="repeats", fix="use --repeats 1 or more (10 is the default)")
    base = int(random_state or 0)
    notes: list[str] = []
    repeats: list[Repeat] = []
    if split == "grouped":
        _check_folds(n_splits)
        n_groups = len(np.unique(groups))
        if n_splits > n_groups:
            notes.append(f"grouped split: --folds {n_splits} cut to {n_groups}, the number of positions in the dataset")
        partitions: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for r in range(n_repeats):
            k = min(n_splits, n_groups)
            seed = base + r // k
            if seed not in partitions:
                partitions[seed] = grouped_folds(groups, n_splits, seed)
            train, test = partitions[seed][r % k]
            repeats.append(Repeat(r, seed, train, test))
    else:
        for r in range(n_repeats):
            train, test = split_folds(split, groups, base + r, n_splits)[0]
            repeats.append(Repeat(r, base + r, train, test))
    n_test = min(len(rep.test) for rep in repeats)
    if n_test < MIN_TEST_ROWS:
        notes.append(
            f"{split} split: only {n_test} test presses per repeat (fewer than {MIN_TEST_ROWS}); a share within "
            f"the probe radius moves in steps of {100 / n_test:.0f} % per press: record more presses"
        )
    for rep in repeats:
        if len(rep.train) < MIN_TRAIN_ROWS:
            raise DataError(
                f"only {len(rep.train)} training presses in a {split} repeat",
                field="rows",
                fix=f"record at least {MIN_TRAIN_ROWS} presses per fold",
            )
    return repeats, notes


@dataclass(frozen=True)
class ModelResult:
    """One model on one split over its repeats: per-repeat errors, their summary, timings, example predictions.

    y_true_mm / y_pred_mm / groups: the predictions the Fig. 9 ellipses are drawn from (grouped:
    the first k-fold partition, every row once; random and design: repeat 0).
    """

    model: str
    split: str
    per_repeat: tuple[PositionErrors, ...]
    fit_time_s: float  # mean over repeats, one fit each
    predict_time_per_sample_s: float
    n_train_rows: int  # mean over repeats
    y_true_mm: np.ndarray
    y_pred_mm: np.ndarray
    groups: np.ndarray

    @property
    def n_repeats(self) -> int:
        return len(self.per_repeat)

    @property
    def errors(self) -> PositionErrors:
        """Pooled over the example predictions (see the class docstring)."""
        return position_errors(self.y_true_mm, self.y_pred_mm)

    @property
    def summary(self) -> dict[str, Interval]:
        return summarise_repeats(list(self.per_repeat))

    def row(self) -> dict:
        out: dict = {
            "model": self.model,
            "split": self.split,
            "n_repeats": self.n_repeats,
            "n_test": int(round(np.mean([e.n for e in self.per_repeat]))),
            "n_train": self.n_train_rows,
        }
        for name, iv in self.summary.items():
            scale = 100.0 if name.endswith("_share") else 1.0
            key = name.replace("_share", "_pct") if scale != 1.0 else name
            out[key] = scale * iv.mean
            out[f"{key}_std"] = scale * iv.std
            # every figure is >= 0 (shares <= 100 %): the interval is cut there, never drawn below zero
            high = 100.0 if scale != 1.0 else np.inf
            out[f"{key}_lo"] = float(np.clip(scale * iv.low, 0.0, high))
            out[f"{key}_hi"] = float(np.clip(scale * iv.high, 0.0, high))
        # the repeat with the lowest test MSE, as the paper picked its best of 10 networks (Fig. 9): set beside the
        # paper's best network, not the average of ours (the report's "The paper beside this dataset")
        best = min(self.per_repeat, key=lambda e: e.mse_mm2)
        out["best_mean_error_mm"] = best.mean_error_mm
        out["best_within_probe_pct"] = 100.0 * best.within_probe_share
        out["best_mse_per_coordinate_mm2"] = best.mse_per_coordinate_mm2
        out["fit_time_s"] = self.fit_time_s
        out["predict_time_per_sample_us"] = 1e6 * self.predict_time_per_sample_s
        return out


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


def _takes_groups(estimator: BaseEstimator) -> bool:
    return getattr(estimator, "_validates_on_groups", False) is True


def fit_predict(
    estimator: BaseEstimator,
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray | None,
    train: np.ndarray,
    test: np.ndarray,
) -> tuple[np.ndarray, float, float]:
    """Fit a clone on the training rows, predict the test rows: (predictions, fit s, predict s).

    An estimator that validates on held-out positions (the LM network) gets the training rows'
    groups, so its validation rows are whole positions it does not train on.
    """
    model = clone(estimator)
    start = time.perf_counter()
    if groups is not None and _takes_groups(model):
        model.fit(X[train], y[train], groups=groups[train])
    else:
        model.fit(X[train], y[train])
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    pred = np.asarray(model.predict(X[test]), dtype=float)
    return pred, fit_s, time.perf_counter() - start


def _collect(
    name: str,
    split: str,
    repeats: Sequence[Repeat],
    outputs: Sequence[tuple[np.ndarray, float, float]],
    y: np.ndarray,
    groups: np.ndarray,
) -> ModelResult:
    per_repeat = []
    for rep, (pred, _, _) in zip(repeats, outputs):
        if not np.isfinite(pred).all():
            raise DataError(
                f"model {name} predicted non-finite positions",
                field=name,
                fix="report this dataset: every baseline should give finite predictions",
            )
        per_repeat.append(position_errors(y[rep.test], pred))
    # example predictions: grouped -> the first partition (same seed as repeat 0), else repeat 0
    first = [i for i, rep in enumerate(repeats) if rep.seed == repeats[0].seed] if split == "grouped" else [0]
    rows = np.concatenate([repeats[i].test for i in first])
    preds = np.concatenate([outputs[i][0] for i in first])
    n_pred = sum(len(rep.test) for rep in repeats)
    return ModelResult(
        model=name,
        split=split,
        per_repeat=tuple(per_repeat),
        fit_time_s=float(np.mean([o[1] for o in outputs])),
        predict_time_per_sample_s=float(sum(o[2] for o in outputs) / max(n_pred, 1)),
        n_train_rows=int(np.mean([len(rep.train) for rep in repeats])),
        y_true_mm=y[rows],
        y_pred_mm=preds,
        groups=groups[rows],
    )


def result_from_predictions(
    name: str,
    split: str,
    repeats: Sequence[Repeat],
    predictions: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    predict_time_per_sample_s: float,
) -> ModelResult:
    """A model that needs no training (the physics inversion): its predictions of every row, cut per repeat."""
    outputs = [(predictions[rep.test], 0.0, predict_time_per_sample_s * len(rep.test)) for rep in repeats]
    return _collect(name, split, repeats, outputs, y, groups)


def fit_tasks(
    estimators: Mapping[str, BaseEstimator],
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    split_repeats: Mapping[str, Sequence[Repeat]],
    costs_s: Mapping[str, float] | None = None,
    row_caps: Mapping[str, int] | None = None,
) -> list[Task]:
    """One task per (split, model, repeat), keyed so; costs_s: estimated seconds per fit of each model (ordering).

    The grouped split's fits get the training rows' position ids (an estimator that validates on
    held-out positions uses them); fits on a split by row do not: there the LM validates on random
    rows, as the paper did. row_caps: a model with more training rows than its cap trains on
    `even_draw` of them (keyed by the repeat's seed); its test rows are all the repeat's.
    """
    check_arrays(X, y)
    costs_s, row_caps = costs_s or {}, row_caps or {}

    def train_rows(name: str, rep: Repeat) -> np.ndarray:
        cap = row_caps.get(name)
        return rep.train if cap is None else even_draw(rep.train, groups, cap, rep.seed)

    return [
        Task(
            (s, n, rep.index),
            float(costs_s.get(n, 1.0)),
            fit_predict,
            (estimators[n], X, y, groups if s == "grouped" else None, train_rows(n, rep), rep.test),
        )
        for s, reps in split_repeats.items()
        for n in estimators
        for rep in reps
    ]


def even_draw(rows: np.ndarray, groups: np.ndarray, cap: int, seed: int) -> np.ndarray:
    """At most `cap` of `rows` (sorted), drawn as evenly as possible over their positions (groups): every
    position gives its k-th row (in a random order keyed by seed) before any gives its (k+1)-th.
    Rows unchanged when there are no more than cap."""
    rows = np.asarray(rows)
    if len(rows) <= cap:
        return rows
    shuffled = rows[np.random.default_rng(seed).permutation(len(rows))]
    _, group = np.unique(np.asarray(groups)[shuffled], return_inverse=True)
    by_group = np.argsort(group, kind="stable")  # each position's rows together, in the shuffled order
    starts = np.searchsorted(group[by_group], group[by_group])  # first index of each row's position
    rank = np.empty(len(rows), dtype=np.int64)
    rank[by_group] = np.arange(len(rows)) - starts  # the row's turn within its position
    chosen = np.lexsort((np.arange(len(rows)), rank))[:cap]  # turn 0 of every position, then turn 1, ...
    return np.sort(shuffled[chosen])


def collect_results(
    names: Sequence[str],
    split_repeats: Mapping[str, Sequence[Repeat]],
    outputs: Mapping,
    y: np.ndarray,
    groups: np.ndarray,
) -> list[ModelResult]:
    """The fit tasks' outputs (keyed as `fit_tasks` keys them) as results in (split, model) order."""
    return [
        _collect(n, s, reps, [outputs[(s, n, rep.index)] for rep in reps], y, groups)
        for s, reps in split_repeats.items()
        for n in names
    ]


def evaluate_models(
    estimators: Mapping[str, BaseEstimator],
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    split_repeats: Mapping[str, Sequence[Repeat]],
    n_jobs: int = 1,
    backend: str | None = None,
    progress=None,
    costs_s: Mapping[str, float] | None = None,
    row_caps: Mapping[str, int] | None = None,
) -> list[ModelResult]:
    """Every (split, model, repeat) fit as one task (see `fit_tasks`); results in (split, model) order.

    n_jobs: processes, this one among them (1 = only this one, -1 = every core). backend: a joblib backend name
    (none by default: the tasks' own lanes; "dask" with a dask.distributed client registered).
    progress: optional callable(done_tasks, total_tasks). costs_s: estimated seconds per fit by
    model name: in processes the costliest fits start first (the results do not depend on it).
    """
    tasks = fit_tasks(estimators, X, y, groups, split_repeats, costs_s, row_caps)
    outputs = run_tasks(tasks, n_jobs=n_jobs, backend=backend, progress=progress)
    return collect_results(list(estimators), split_repeats, outputs, y, groups)


def evaluate_model(
    name: str,
    estimator: BaseEstimator,
    X: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    split: str = "grouped",
    random_state: int | None = 0,
    n_splits: int = 5,
    *,
    n_repeats: int | None = None,
    n_jobs: int = 1,
) -> ModelResult:
    """One model on one split over its repeats (default: grouped, one k-fold partition; others 1 repeat)."""
    if n_repeats is None:
        n_repeats = min(n_splits, len(np.unique(groups))) if split == "grouped" else 1
    check_arrays(X, y)
    repeats, notes = repeat_splits(split, groups, n_repeats, random_state, n_splits)
    for note in notes:
        logger.warning(note)
    return evaluate_models({name: estimator}, X, y, groups, {split: repeats}, n_jobs=n_jobs)[0]

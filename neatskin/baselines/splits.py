"""The baselines' splits: the paper's 95/3/2 by row, k-fold over positions, the 11 x 6 test design, and their repeats.

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

Anything that makes a figure weak (few test rows, folds cut) is returned as a warning text.
`neatskin.baselines.evaluate` fits and scores the models on them (and re-exports the split functions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.model_selection import GroupKFold

from neatskin.errors import DataError

PAPER_FRACTIONS = (0.95, 0.03, 0.02)
SPLITS = ("grouped", "random", "design")
DESIGN_POSITIONS = 11
DESIGN_PRESSES = 6
MIN_TRAIN_ROWS = 6
MIN_TEST_ROWS = 20  # below this a share moves in steps of 5 % or more per press


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

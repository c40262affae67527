"""Predictions off the skin: the box every model's predictions are clipped to, and the report's account of which
repeats and positions fell off it and why.

The press is on the skin, so every model's prediction is projected onto the skin's box (`prediction_box_mm`)
before it is scored. The Euclidean projection onto a convex set that holds the true position never moves a
prediction further from it, so clipping can only lower an error; it has no parameter to tune. k-NN and the
extra trees answer inside the box by construction (averages of training positions) and the inversion searches inside it; ridge, the
MLP and the LM network (linear output layers) do not: on a grouped split a test position whose presses cut a set
of pairs no training press cut lands them far off the skin
(docs/baselines.md, "Ridge off the skin"). The report gives every model's clipped share and its error before
clipping beside the error after, so the extrapolation stays in sight (`offskin_text`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from neatskin.baselines.tabletext import sig3

if TYPE_CHECKING:  # evaluate imports this module: its types only for the checker
    from neatskin.baselines.dataset import BaselineData
    from neatskin.baselines.evaluate import ModelResult, Repeat

Box = tuple[float, float, float, float]  # (x_min, y_min, x_max, y_max), mm


def prediction_box_mm(layout: object | None, y_mm: np.ndarray) -> Box:
    """The box predictions are clipped to: the layout's junctions widened by half its widest channel (the position
    strategies place presses on the channel strips and in the faces, gcode/positions.py), grown to hold every
    commanded position of the dataset (the protocol's plan, fixed before any press), so that it holds every label.
    Without a layout: the commanded positions' extent."""
    y_mm = np.asarray(y_mm, dtype=float).reshape(-1, 2)
    lo, hi = y_mm.min(axis=0), y_mm.max(axis=0)
    if layout is not None:
        x0, y0, x1, y1 = layout.bounds_mm  # type: ignore[attr-defined]
        half = max((c.width_mm for c in layout.channels), default=0.0) / 2  # type: ignore[attr-defined]
        lo = np.minimum(lo, [x0 - half, y0 - half])
        hi = np.maximum(hi, [x1 + half, y1 + half])
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def clip_to_box(pred_mm: np.ndarray, box: Box) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) predictions projected onto the box (per coordinate: the Euclidean projection onto a box), and which
    rows moved. Pure."""
    pred_mm = np.asarray(pred_mm, dtype=float)
    clipped = np.clip(pred_mm, [box[0], box[1]], [box[2], box[3]])
    return clipped, np.any(clipped != pred_mm, axis=1)


def _cut_sets(X: np.ndarray, saturation_ohm: Sequence[float]) -> list[frozenset[int]]:
    """Per row, the pair columns holding their saturation value (a cut pair, dataset.saturate)."""
    cut = X == np.asarray(saturation_ohm, dtype=float)[None, :]
    return [frozenset(np.flatnonzero(row).tolist()) for row in cut]


def unseen_cut_rows(
    X: np.ndarray, saturation_ohm: Sequence[float], train: np.ndarray, test: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For the test rows: whether each cut a pair, and whether its set of cut pairs is one no training row has."""
    if len(saturation_ohm) != X.shape[1]:
        return np.zeros(len(test), dtype=bool), np.zeros(len(test), dtype=bool)
    sets = _cut_sets(X, saturation_ohm)
    seen = {sets[i] for i in train}
    cut = np.array([bool(sets[i]) for i in test], dtype=bool)
    return cut, np.array([bool(sets[i]) and sets[i] not in seen for i in test], dtype=bool)


def _common_electrode(columns: Sequence[str]) -> str:
    """ "electrode 2's 7 pairs" when the cut pairs share one electrode, else "7 pairs"."""
    pairs = [set(c.split("_")[2:]) for c in columns]
    common = set.intersection(*pairs) if pairs else set()
    count = f"{len(columns)} pair{'s' * (len(columns) != 1)}"
    return f"electrode {sorted(common)[0]}'s {count}" if len(common) == 1 and len(columns) > 1 else count


def _repeat_note(result: ModelResult, repeats: Sequence[Repeat], size_mm: float, data: BaselineData) -> str:
    """The repeat clipping changed most, the positions with a clipped prediction farther off than the skin is wide,
    and whether those positions' presses cut a set of pairs no training press of the repeat cut."""
    change = [u.mean_error_mm - c.mean_error_mm for u, c in zip(result.unclipped_per_repeat, result.per_repeat)]
    k = int(np.argmax(change))
    rep = repeats[k]
    far = sorted(p for p, m in result.clipped_positions[k] if m > size_mm)
    if not far:
        return ""
    raw, clipped = result.unclipped_per_repeat[k].mean_error_mm, result.per_repeat[k].mean_error_mm
    largest = max(m for _, m in result.clipped_positions[k])
    note = (
        f" Repeat {k} changed most (mean error {sig3(raw)} mm unclipped, {sig3(clipped)} mm clipped): "
        f"position{'s' * (len(far) > 1)} {', '.join(str(p) for p in far)} had predictions farther from the press "
        f"than the skin is wide ({sig3(size_mm)} mm), up to {sig3(largest)} mm."
    )
    cut, unseen = unseen_cut_rows(data.X, data.saturation_ohm, rep.train, rep.test)
    at_far = np.isin(data.groups[rep.test], far)
    if (unseen & at_far).any() and not (cut & at_far & ~unseen).any():
        sets = sorted(set(_cut_sets(data.X[rep.test[unseen & at_far]], data.saturation_ohm)), key=sorted)
        what = "; ".join(_common_electrode([data.pair_columns[c] for c in sorted(cut_set)]) for cut_set in sets)
        columns = sorted(set().union(*sets))
        trained = data.X[rep.train][:, columns] == np.asarray(data.saturation_ohm)[columns]
        if trained.any(axis=0).all():
            what += ", each pair cut in training only beside other pairs"
        note += (
            f" Every press of theirs that cut a pair ({int((unseen & at_far).sum())}) cut a set no training press "
            f"of that repeat cut ({what}): a pattern outside the training data"
            + (
                ", where a linear model adds up their saturated dR and extrapolates."
                if result.model == "ridge"
                else "."
            )
        )
    return note


def offskin_text(
    table: pd.DataFrame,
    results: Sequence[ModelResult],
    box: Box | None,
    split_repeats: Mapping[str, Sequence[Repeat]],
    data: BaselineData,
) -> list[str]:
    """report.md's "Predictions off the skin": the box, and per model and split that had a prediction clipped, how
    many, its mean error before and after, and the repeat and positions most of them came from."""
    if box is None:
        return []
    lines = [
        "## Predictions off the skin",
        "",
        f"Every model's predictions are clipped to the skin's box, x {box[0]:g} to {box[2]:g} mm, y {box[1]:g} to "
        f"{box[3]:g} mm (the layout's junctions widened by half its widest channel, where presses are placed, and "
        "every commanded position), before they are scored: the press is on the skin, and a prediction moved onto a "
        "box that holds every true position is never further from it. k-NN and the extra trees answer inside it by "
        "construction (averages of training positions) and the inversion searches inside it; ridge and the LM "
        "network (a linear output layer) do not.",
        "",
    ]
    rows = {(r.model, r.split): r for r in table.itertuples(index=False)}
    size_mm = max(box[2] - box[0], box[3] - box[1])
    clipped = [r for r in results if sum(r.clipped_per_repeat)]
    if not clipped:
        return [*lines, "No prediction fell off the skin.", ""]
    for result in clipped:
        row = rows[(result.model, result.split)]
        n = sum(e.n for e in result.per_repeat)
        moved = sum(result.clipped_per_repeat)
        line = (
            f"- `{result.model}` ({result.split}): {moved:,} of {n:,} predictions ({sig3(100 * moved / n)} %) clipped; "
            f"mean error {sig3(row.unclipped_mean_error_mm)} ± {sig3(row.unclipped_mean_error_mm_std)} mm unclipped, "
            f"{sig3(row.mean_error_mm)} ± {sig3(row.mean_error_mm_std)} mm clipped (over the same {result.n_repeats} "
            "repeats)."
        )
        line += _repeat_note(result, split_repeats[result.split], size_mm, data)
        lines.append(line)
    return [*lines, ""]

"""Predictions off the skin: every model's predictions are clipped to the skin's box before they are scored; the
projection never moves one further from a press on the skin; a grouped test position whose presses cut a set of
pairs no training press cut (outside the training data) sends ridge off the skin, and the report names the repeat,
the positions and the cut set, with the error before and after clipping."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.baselines.evaluate import BaselineWarning, collect_results, fit_predict
from neatskin.baselines.metrics import position_errors
from neatskin.baselines.models import make_model
from neatskin.baselines.offskin import clip_to_box, prediction_box_mm
from neatskin.baselines.report import run_baselines
from neatskin.baselines.splits import repeat_splits
from neatskin.layout import load_layout

REPO = Path(__file__).resolve().parent.parent
PAPER_SKIN = REPO / "protocols" / "skins" / "paper.toml"
LAYOUT = load_layout(PAPER_SKIN)
PAIRS = [(p.i, p.j) for p in LAYOUT.pairs]
ELECTRODES = {e.number: LAYOUT.xy_mm[e.junction] for e in LAYOUT.electrodes}

coordinate = st.floats(-1e4, 1e4, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(
    corner=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    size=st.tuples(st.floats(0, 60), st.floats(0, 60)),
    truth_share=st.tuples(st.floats(0, 1), st.floats(0, 1)),
    pred=st.lists(st.tuples(coordinate, coordinate), min_size=1, max_size=8),
)
def test_clipping_never_moves_a_prediction_further_from_a_press_inside_the_box(corner, size, truth_share, pred):
    box = (corner[0], corner[1], corner[0] + size[0], corner[1] + size[1])
    truth = np.array([[box[0] + truth_share[0] * size[0], box[1] + truth_share[1] * size[1]]] * len(pred))
    truth = np.clip(truth, box[:2], box[2:])  # float rounding of corner + share * size
    raw = np.array(pred, dtype=float)
    clipped, moved = clip_to_box(raw, box)
    assert np.all(np.linalg.norm(clipped - truth, axis=1) <= np.linalg.norm(raw - truth, axis=1) + 1e-9)
    assert np.all((clipped >= box[:2]) & (clipped <= box[2:]))  # inside the box
    assert np.array_equal(clipped[~moved], raw[~moved])  # a prediction inside stays where it is
    again, moved_again = clip_to_box(clipped, box)  # a projection: clipping twice is clipping once
    assert np.array_equal(again, clipped) and not moved_again.any()


def test_the_box_is_the_junctions_widened_by_half_the_widest_channel_and_holds_every_label():
    half = max(c.width_mm for c in LAYOUT.channels) / 2  # 1 mm on the paper skin: channels 2 mm wide
    x0, y0, x1, y1 = LAYOUT.bounds_mm
    inside = np.array([[5.0, 5.0], [29.0, 1.0]])
    assert prediction_box_mm(LAYOUT, inside) == (x0 - half, y0 - half, x1 + half, y1 + half) == (-1, -1, 31, 31)
    beyond = np.array([[-3.0, 5.0], [12.0, 40.0]])  # commanded positions off the layout: the box grows to hold them
    assert prediction_box_mm(LAYOUT, beyond) == (-3.0, -1.0, 31.0, 40.0)
    assert prediction_box_mm(None, beyond) == (-3.0, 5.0, 12.0, 40.0)  # no layout: the labels' extent


def cut_table(seed: int = 7, repeats: int = 4) -> pd.DataFrame:
    """16 grid positions with dR linear in the position, and beside each of the 8 electrodes one position whose
    presses cut that electrode (its 7 pairs +inf, flagged open_circuit and clipped as acquisition/demod.py flags
    them): each electrode's cut set is at one position only, so a grouped fold that tests it never trained on it."""
    rng = np.random.default_rng(seed)
    grid = [((x, y), None) for x in (6.0, 12.0, 18.0, 24.0) for y in (6.0, 12.0, 18.0, 24.0)]
    beside = [(tuple(np.clip(xy, 2.0, 28.0)), n) for n, xy in ELECTRODES.items()]
    slopes = rng.normal(0.0, 50.0, size=(len(PAIRS), 2))
    rows = []
    for pid, ((x, y), cut) in enumerate(grid + beside):
        for _ in range(repeats):
            dr = slopes @ np.array([x, y]) + rng.normal(0.0, 1.0, len(PAIRS))
            flags = [f"{kind}:{i}-{j}" for i, j in PAIRS if cut in (i, j) for kind in ("open_circuit", "clipped")]
            dr[[k for k, p in enumerate(PAIRS) if cut in p]] = np.inf
            row = {"campaign": "synthetic", "press_id": len(rows), "position_id": pid, "x_mm": x, "y_mm": y}
            rows.append(row | {"flags": flags} | {f"dR_ohm_{i}_{j}": dr[k] for k, (i, j) in enumerate(PAIRS)})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def cut_report(tmp_path_factory):
    df = cut_table()
    folder = tmp_path_factory.mktemp("cut")
    df.to_parquet(folder / "presses.parquet", index=False)
    (folder / "manifest.json").write_text(json.dumps({"layout": {"path": str(PAPER_SKIN)}, "status": "complete"}))
    with pytest.warns(BaselineWarning, match="only 16 test presses"):  # 96 presses in 5 folds: said, not hidden
        report = run_baselines(folder, split="grouped", models=["ridge", "knn"], n_repeats=5, progress=False, n_jobs=1)
    return df, report


def test_a_test_position_whose_cut_set_no_training_press_had_sends_ridge_off_the_skin_and_the_report_says_so(
    cut_report,
):
    df, report = cut_report
    ridge = next(r for r in report.results if r.model == "ridge")
    knn = next(r for r in report.results if r.model == "knn")
    # independently of the report: ridge's own predictions, repeat by repeat, on the loader's saturated features
    from neatskin.baselines.dataset import load_baseline_data

    data = load_baseline_data(Path(report.files["report"]).parent)
    box = (-1.0, -1.0, 31.0, 31.0)
    cut_of = {  # the electrode every flagged pair of a position shares (its flags name "<kind>:<i>-<j>")
        pid: set.intersection(*({int(e) for e in f.split(":")[1].split("-")} for f in flags)).pop()
        if len(flags)
        else None
        for pid, flags in df.groupby("position_id")["flags"].first().items()
    }
    repeats, _ = repeat_splits("grouped", data.groups, 5, 0, 5)
    raw_errors, changes, far = [], [], []
    for rep in repeats:
        pred, _, _ = fit_predict(make_model("ridge"), data.X, data.y, data.groups, rep.train, rep.test)
        err = np.hypot(*(pred - data.y[rep.test]).T)
        clipped_err = np.hypot(*(clip_to_box(pred, box)[0] - data.y[rep.test]).T)
        raw_errors.append(err)
        changes.append(err.mean() - clipped_err.mean())
        far.append(sorted(set(data.groups[rep.test][err > 32.0].tolist())))
        assert np.all(clipped_err <= err + 1e-9)  # never further
    k = int(np.argmax(changes))
    assert far[k], "the constructed case must send ridge farther off than the skin is wide (the precondition)"
    far_cuts = {cut_of[p] for p in far[k]}
    trained_cuts = {cut_of[p] for p in np.unique(data.groups[repeats[k].train]).tolist()}
    assert (
        None not in far_cuts and not far_cuts & trained_cuts
    )  # each far position cuts an electrode no training press cut

    # the result: scored clipped, with the model's own errors beside
    assert [e.mean_error_mm for e in ridge.unclipped_per_repeat] == pytest.approx([e.mean() for e in raw_errors])
    assert all(c.mean_error_mm <= u.mean_error_mm for c, u in zip(ridge.per_repeat, ridge.unclipped_per_repeat))
    assert ridge.per_repeat[k].max_error_mm < ridge.unclipped_per_repeat[k].max_error_mm
    assert np.all((ridge.y_pred_mm >= -1.0) & (ridge.y_pred_mm <= 31.0))
    moved = sum(ridge.clipped_per_repeat)
    assert moved > 0
    row = report.table.set_index(["model", "split"]).loc[("ridge", "grouped")]
    assert row["clipped_pct"] == pytest.approx(100 * moved / len(df))
    assert row["unclipped_mean_error_mm"] == pytest.approx(np.mean([e.mean() for e in raw_errors]))
    assert row["mean_error_mm"] < row["unclipped_mean_error_mm"]
    # k-NN averages training positions: inside the box by construction, never clipped
    assert sum(knn.clipped_per_repeat) == 0 and knn.per_repeat == knn.unclipped_per_repeat

    # the report: the box, the counts, the repeat, the positions, the cut sets
    text = report.text.split("## Predictions off the skin")[1].split("\n## ")[0]
    assert "x -1 to 31 mm, y -1 to 31 mm" in text
    assert f"`ridge` (grouped): {moved:,} of {len(df):,} predictions" in text
    assert f"Repeat {k} changed most" in text
    assert f"{', '.join(str(p) for p in far[k])} had predictions farther from the press than the skin is wide" in text
    for electrode in sorted(far_cuts):
        assert f"electrode {electrode}'s 7 pairs" in text
    assert "a linear model adds up their saturated dR and extrapolates" in text
    assert "`knn` (grouped)" not in text  # nothing clipped, nothing listed


def test_without_a_box_nothing_is_clipped_and_the_figures_are_the_models_own():
    rng = np.random.default_rng(3)
    y = rng.uniform(0, 30, size=(40, 2))
    groups = np.repeat(np.arange(10), 4)
    repeats, _ = repeat_splits("grouped", groups, 2, 0, 2)
    outputs = {("grouped", "m", rep.index): (y[rep.test] * 3.0 - 20.0, 0.0, 0.0) for rep in repeats}  # far off
    plain = collect_results(["m"], {"grouped": repeats}, outputs, y, groups)[0]
    boxed = collect_results(["m"], {"grouped": repeats}, outputs, y, groups, (0.0, 0.0, 30.0, 30.0))[0]
    assert plain.clipped_per_repeat == () and plain.row()["clipped_pct"] == 0.0
    assert plain.row()["unclipped_mean_error_mm"] == plain.row()["mean_error_mm"]
    assert plain.per_repeat[0] == position_errors(y[repeats[0].test], outputs[("grouped", "m", 0)][0])
    assert boxed.row()["unclipped_mean_error_mm"] == pytest.approx(plain.row()["mean_error_mm"])
    assert boxed.row()["mean_error_mm"] < plain.row()["mean_error_mm"]
    assert sum(boxed.clipped_per_repeat) > 0

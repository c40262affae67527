"""The report's figures read as a scientist needs: a linear error axis near the models with the floors drawn
under their names, one colour bar per bound-map panel fitted to its own values, the skin outline in view."""

import dataclasses
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import LogNorm, Normalize
from test_baselines_report import small_table, write_dataset

from neatskin.baselines.plots import (
    bound_map_figure,
    error_vs_time_figure,
    floors_mm,
    plot_error_ellipses,
)
from neatskin.baselines.report import run_baselines
from neatskin.baselines.reporttext import _bound_text
from neatskin.baselines.tabletext import flag_text, sig3
from neatskin.layout import load_layout
from neatskin.tomlfile import resolve_path


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    folder = write_dataset(
        tmp_path_factory.mktemp("plots") / "ds", small_table(12, 4), layout=True, crb_mm=0.004, crb_nuisance_mm=1.5
    )
    with pytest.warns(UserWarning):
        return run_baselines(folder, split="grouped", models=["knn", "extra_trees"], progress=False, n_repeats=3)


def test_floors_are_pooled_per_column_and_named_and_a_missing_column_is_left_out():
    limit = pd.DataFrame({"crb_mm": [0.3, 0.4], "crb_nuisance_mm": [1.0, 2.6]})
    floors = floors_mm(limit)
    assert list(floors) == [
        "Cramér-Rao bound, electronics only",
        "Cramér-Rao bound with depth, drift, placement (nuisance floor)",
    ]
    assert floors["Cramér-Rao bound, electronics only"][0] == pytest.approx(np.sqrt(0.125))  # sqrt((.09 + .16) / 2)
    assert floors["Cramér-Rao bound with depth, drift, placement (nuisance floor)"][0] == pytest.approx(np.sqrt(3.88))
    # a bound beyond the skin (extent_mm) at one position is compared with nothing, so not drawn either
    beyond = pd.DataFrame({"crb_mm": [0.3, 40.0], "crb_nuisance_mm": [1.0, np.inf]})
    assert floors_mm(beyond, extent_mm=30.0) == {} and len(floors_mm(beyond.assign(crb_mm=4.0), 30.0)) == 1
    limit["label_noise_floor_mm"] = [0.5, 0.5]
    assert floors_mm(limit)["label-noise floor (landing point vs commanded)"][0] == pytest.approx(0.5)
    assert floors_mm(None) == {} and floors_mm(limit.iloc[:0]) == {}


def test_error_axis_is_linear_from_zero_near_the_models_with_every_floor_drawn_and_named(report):
    limit = report.table  # the bounds of the fixture: 0.004 mm electronics only, 1.5 mm with nuisances
    floors = floors_mm(pd.DataFrame({"crb_mm": [0.004], "crb_nuisance_mm": [1.5]}))
    fig = error_vs_time_figure(list(report.results), report.bound_rms_mm, limit, floors)
    try:
        ax = fig.axes[0]
        assert ax.get_yscale() == "linear" and ax.get_xscale() == "log"
        bottom, top = ax.get_ylim()
        highs = [r.summary["mean_error_mm"].high for r in report.results]
        assert bottom == 0.0
        # the axis ends just above the highest interval (or the probe radius): no decades of empty space
        assert max(highs) < top <= 1.1 * max(max(highs), 2.75) + 1e-9
        labels = [t.get_text() for t in fig.legends[0].get_texts()]
        assert "Cramér-Rao bound, electronics only: 0.004 mm" in labels
        assert "Cramér-Rao bound with depth, drift, placement (nuisance floor): 1.5 mm" in labels
        assert {"knn", "extra_trees"} <= set(labels) and not ax.texts  # none off the view
        floor_lines = [ln.get_ydata()[0] for ln in ax.get_lines() if ln.get_linestyle() in ("-.", "--")]
        assert 0.004 in floor_lines and 1.5 in floor_lines
        # each model's bar is its 95 % interval of the mean, drawn at full length on the linear axis
        for r in (r for r in report.results if r.split == "grouped"):
            s = r.summary["mean_error_mm"]
            assert bottom <= max(s.low, 0.0) and s.high <= top
    finally:
        plt.close(fig)


def test_a_model_far_off_is_drawn_on_the_top_edge_with_its_value_not_stretching_the_axis(report):
    results: list = list(report.results)
    far = results[0]
    s = far.summary["mean_error_mm"]
    scale = 1000.0
    off = dataclasses.replace(s, mean=s.mean * scale, low=s.low * scale, high=s.high * scale)
    results[0] = SimpleNamespace(  # the figure reads only these fields of a ModelResult
        model=far.model,
        split=far.split,
        summary={**far.summary, "mean_error_mm": off},
        fit_time_s=far.fit_time_s,
        predict_time_per_sample_s=far.predict_time_per_sample_s,
        per_repeat=far.per_repeat,
    )
    fig = error_vs_time_figure(results, None, None, {})
    try:
        ax = fig.axes[0]
        top = ax.get_ylim()[1]
        others = [r.summary["mean_error_mm"].high for r in results[1:]]
        assert top <= 1.1 * max(*others, 2.75) + 1e-9  # the others' scale, not the extrapolating model's
        notes = [t.get_text() for t in ax.texts]
        assert f"{s.mean * scale:.3g} mm" in notes
    finally:
        plt.close(fig)


def test_bound_map_gives_each_panel_its_own_colour_bar_fitted_to_its_values():
    limit = pd.DataFrame(
        {
            "position_id": [0, 1, 2],
            "x_mm": [5.0, 15.0, 25.0],
            "y_mm": [5.0, 15.0, 25.0],
            "crb_mm": [0.001, 0.01, 0.05],  # decades: a log scale
            "crb_nuisance_mm": [1.9, 1.91, 1.95],  # nearly one value: a linear scale over its own range
        }
    )
    fig = bound_map_figure(limit)
    try:
        from matplotlib.collections import PathCollection

        images = [c for ax in fig.axes for c in ax.collections if isinstance(c, PathCollection)]
        assert len(images) == 2
        elec, nuis = images
        assert isinstance(elec.norm, LogNorm) and (elec.norm.vmin, elec.norm.vmax) == (0.001, 0.05)
        assert type(nuis.norm) is Normalize and (nuis.norm.vmin, nuis.norm.vmax) == (1.9, 1.95)
        assert len(fig.axes) == 4  # two panels, two colour bars
    finally:
        plt.close(fig)


def test_bound_map_keeps_infinite_and_beyond_the_skin_positions_off_its_colour_scale():
    """One position at 2e6 mm (just off a channel the probe shuts) had stretched the panel's log scale to six
    decades, the other positions all one colour: it is an orange cross, an infinite one a red cross, and the scale
    spans the others (0.9 to 1.1 mm: linear). The title gives the median, no RMS held by those positions."""
    limit = pd.DataFrame(
        {
            "position_id": [0, 1, 2, 3, 4],
            "x_mm": [5.0, 15.0, 25.0, 5.0, 25.0],
            "y_mm": [5.0, 15.0, 25.0, 25.0, 5.0],
            "crb_mm": [0.9, 1.0, 1.1, 2e6, np.inf],
        }
    )
    fig = bound_map_figure(limit)  # no layout: the skin's extent is the positions' spread, 20 mm
    try:
        from matplotlib.collections import PathCollection

        (image,) = [c for ax in fig.axes for c in ax.collections if isinstance(c, PathCollection)]
        assert type(image.norm) is Normalize and (image.norm.vmin, image.norm.vmax) == (0.9, 1.1)
        ax = fig.axes[0]
        crosses = {line.get_label(): (tuple(line.get_xdata()), tuple(line.get_ydata())) for line in ax.get_lines()}
        assert crosses["beyond the skin (> 20 mm): 1"] == ((5.0,), (25.0,))
        assert crosses["unobservable (+inf): 1"] == ((25.0,), (5.0,))
        assert ax.get_title() == "electronics only\nmedian 1.1 mm over 5 positions"
    finally:
        plt.close(fig)


def test_bound_map_draws_the_landing_point_bound_with_the_files_infinite_count():
    """With `landing_bound_mm` (report.md's landing-point bound) a third panel: each panel's red-cross count is the
    file's count of +inf in its column, at those positions."""
    limit = pd.DataFrame(
        {
            "position_id": [0, 1, 2, 3],
            "x_mm": [5.0, 15.0, 25.0, 5.0],
            "y_mm": [5.0, 15.0, 25.0, 25.0],
            "crb_mm": [0.01, np.inf, 0.02, np.inf],
            "crb_nuisance_mm": [1.0, np.inf, 1.1, np.inf],
            "landing_bound_mm": [0.1, np.inf, 0.3, np.inf],
        }
    )
    fig = bound_map_figure(limit)
    try:
        panels = [ax for ax in fig.axes if ax.get_xlabel() == "x (mm)"]
        assert [ax.get_title().splitlines()[0] for ax in panels] == [
            "electronics only",
            "depth, drift, placement as nuisances",
            "landing point: depth, drift, fabrication as nuisances",
        ]
        for ax in panels:
            (line,) = ax.get_lines()
            assert line.get_label() == "unobservable (+inf): 2"
            assert (tuple(line.get_xdata()), tuple(line.get_ydata())) == ((15.0, 5.0), (15.0, 25.0))
    finally:
        plt.close(fig)


def test_ellipses_keep_the_whole_skin_outline_in_view(report, tmp_path):
    layout = load_layout(resolve_path("protocols/skins/paper.toml"))
    x0, y0, x1, y1 = layout.bounds_mm
    captured = {}
    real_close = plt.close

    def keep(fig):
        captured["fig"] = fig

    plt.close = keep
    try:
        plot_error_ellipses([r for r in report.results if r.split == "grouped"], tmp_path / "e.png", layout)
    finally:
        plt.close = real_close
    fig = captured["fig"]
    for ax in fig.axes:
        if not ax.axison:
            continue
        (left, right), (low, high) = ax.get_xlim(), ax.get_ylim()
        assert left < x0 and right > x1 and low < y0 and high > y1
    plt.close(fig)


# ---------------------------------------------------------------- report.md's text


@pytest.mark.parametrize(
    "value, text",
    [
        (2.0, "2.00"),
        (0.162, "0.162"),
        (43412.0, "43,400"),
        (0.0044321, "0.00443"),
        (9.996, "10.0"),
        (99.96, "100"),
        (0.0, "0"),
        (-1.234, "-1.23"),
        (float("inf"), "inf"),
        (float("nan"), "nan"),
    ],
)
def test_sig3_gives_3_significant_figures_without_scientific_notation(value, text):
    assert sig3(value) == text


def test_report_md_has_a_compact_main_table_and_the_full_table_last_with_no_terminal_column(report):
    text = report.text
    assert "RMS/CRBn" not in text and "terminal" not in text
    main = text.index("| model | split | mean error mm [95 % CI] | RMS mm | within probe % |")
    full = text.index("## All figures")
    assert main < full and text.index("| model | split | repeats | test rows |") > full
    main_rows = [ln for ln in text[main:full].splitlines() if ln.startswith("| knn |")]
    assert len(main_rows) == 1 and main_rows[0].count("|") == 9  # 8 columns
    assert "e+" not in text and "e-0" not in text  # no scientific notation anywhere


def test_the_flag_column_and_the_text_agree_on_what_is_memorisation():
    row = SimpleNamespace(below_bound=False, rms_over_crb_nuisance=0.992)
    assert flag_text(row) == "below the nuisance bound (0.992×)"  # noted, not called memorisation
    assert flag_text(SimpleNamespace(below_bound=True, rms_over_crb_nuisance=0.5)) == "memorisation: below the bound"
    assert flag_text(SimpleNamespace(below_bound=False, rms_over_crb_nuisance=1.2)) == ""
    table = pd.DataFrame({"model": ["knn"], "split": ["random"], "rms_over_crb_nuisance": [0.992]})
    text = "\n".join(_bound_text(0.01, 2.0, table))
    assert "at 0.992 times the bound with nuisances (below it: below the nuisance bound, noted, not flagged" in text
    assert "not flagged as memorisation: the flag is the electronics-only bound alone" in text


def test_the_papers_figure_is_drawn_on_both_readings_of_its_test_set_and_not_on_new_positions():
    from neatskin.baselines.evaluate import ModelResult
    from neatskin.baselines.metrics import position_errors
    from neatskin.baselines.resultstable import results_table

    truth = np.zeros((66, 2))
    results = [
        ModelResult(
            "knn", split, (position_errors(truth, truth + [1.0, 0.0]),) * 2, 0.1, 1e-6, 9, truth, truth, truth[:, 0]
        )
        for split in ("grouped", "random", "design")
    ]
    fig = error_vs_time_figure(results, None, results_table(results, None, None), {})
    try:
        paper = {
            ax.get_title(): [ln.get_label() for ln in ax.get_lines() if ln.get_label().startswith("paper")]
            for ax in fig.axes
            if ax.get_title()
        }
        assert paper == {
            "grouped split": [],
            "random split": ["paper, real skin, its stated 95/3/2 split: 2.03 mm"],
            "design split": ["paper, real skin, its scored 11 x 6 test: 2.03 mm"],
        }
    finally:
        plt.close(fig)

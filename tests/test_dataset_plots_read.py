"""Dataset and skin plots read honestly: colour bars span the data (0..1 for a map with no negative value), a map
of equal repeats has no colour bar to misread, a press drawn from features says it was not recorded, and the
title stays clear of the colour bar."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest
from matplotlib.figure import Figure
from test_datasets_curate import campaign

from neatskin.datasets.manifest import update_manifest
from neatskin.datasets.plots import colour_range, plot_press_map, plot_sensitivity_map
from neatskin.datasets.pressplots import plot_press
from neatskin.skin.plots import colour_scale


@pytest.fixture
def figures(monkeypatch):
    """Every figure saved during the test, kept for reading (savefig still writes the PNG)."""
    saved: list[Figure] = []
    real = Figure.savefig

    def keep(self, *args, **kwargs):
        saved.append(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved


def _colour_bars(fig: Figure):
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


def test_colour_ranges_fit_the_sign_of_the_data():
    assert colour_range(np.array([0.0, 0.3, 1.0])) == (0.0, 1.0)
    assert colour_range(np.array([-0.2, 1.0, np.nan])) == (-1.0, 1.0)
    assert colour_scale(np.array([0.1, 1.0]))[1:] == (0.0, 1.0)
    assert colour_scale(np.array([-1.0, 1.0])) == ("RdBu_r", -1.0, 1.0)


def test_sensitivity_map_bar_runs_0_to_1_and_the_title_clears_it(paper_layout, tmp_path, figures):
    campaign(tmp_path / "c", paper_layout, 30, 2, seed=6)
    plot_sensitivity_map(tmp_path / "c", tmp_path / "s.png")
    fig = figures[-1]
    (bar,) = _colour_bars(fig)
    assert bar.get_ylim() == (0.0, 1.0)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    title = fig.axes[0].title.get_window_extent(renderer)
    assert title.x1 < bar.get_window_extent(renderer).x0  # the title ends before the bar begins


def test_press_map_of_equal_repeats_has_no_colour_bar_and_says_the_count(paper_layout, tmp_path, figures):
    campaign(tmp_path / "c", paper_layout, 8, 3, seed=1)
    plot_press_map(tmp_path / "c", tmp_path / "p.png")
    fig = figures[-1]
    assert _colour_bars(fig) == []
    assert "3 presses at every position" in fig.axes[0].get_title()


def test_press_map_of_unequal_repeats_has_whole_count_ticks(paper_layout, tmp_path, figures):
    folder = tmp_path / "c"
    campaign(folder, paper_layout, 8, 3, seed=1)
    import pandas as pd

    df = pd.read_parquet(folder / "presses.parquet")
    df = df[~((df["position_id"] == df["position_id"].iloc[0]) & (df.index % 3 == 0))]  # one position: fewer
    df.to_parquet(folder / "presses.parquet", index=False)
    update_manifest(folder, fsync=False, counts={"planned": len(df), "completed": len(df)})
    plot_press_map(folder, tmp_path / "p.png")
    fig = figures[-1]
    (bar,) = _colour_bars(fig)
    ticks = [t for t in bar.get_yticks() if bar.get_ylim()[0] <= t <= bar.get_ylim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)
    assert "to 3 presses per position" in fig.axes[0].get_title()


def test_a_press_drawn_from_features_is_labelled_not_recorded(paper_layout, tmp_path, figures):
    folder = tmp_path / "c"
    campaign(folder, paper_layout, 4, 2, seed=2)
    plot_press(folder, 1, tmp_path / "press.png")
    fig = figures[-1]
    assert "not recorded" in fig._suptitle.get_text()
    assert all(any("not recorded" in t.get_text() for t in ax.texts) for ax in fig.axes)
    traces = [ln for ln in fig.axes[1].get_lines() if len(ln.get_xdata()) > 2]
    assert traces and all(ln.get_linestyle() == "--" for ln in traces)

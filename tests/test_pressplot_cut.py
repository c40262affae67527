"""`dataset plot --press ID` on a press that cut pairs off (a channel pinched shut: its row's R = dR = +inf): the cut
pairs are marked 'cut' at the top of the R axis and counted in the title, never silently left out, and drawing the
press warns nothing (R - dR was inf - inf, and max - min of an infinite trace inf - inf: numpy's RuntimeWarning).

The campaigns are small paper-like dry runs (30 positions x 1 press; the FE pinch kernel cuts 7 pairs on press 3),
one storing features only (the schematic) and one with waveforms (the recorded trace, where a cut pair reads about
1e8 ohm: RMS(V) over a collapsed current)."""

from __future__ import annotations

import re
import struct
import warnings
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from neatskin.cli import main
from neatskin.datasets.pressplots import (
    OPEN_FOLD,
    _mark_cut,
    largest_changes,
    open_points,
    press_series,
    press_title,
)
from neatskin.datasets.reader import read_presses

matplotlib.use("Agg")
REPO = Path(__file__).resolve().parent.parent
PRESS = 3  # the first press of the 30 that cuts pairs off on this seed


def _paper_like(tmp: Path, name: str, waveforms: bool) -> Path:
    text = (REPO / "protocols" / "paper.toml").read_text()
    changes = [
        ("count = 100", "count = 30"),
        ("repeats = 28", "repeats = 1"),
        ('"skins/', f'"{REPO}/protocols/skins/'),
        ('"wiring/', f'"{REPO}/protocols/wiring/'),
        ('"printers/', f'"{REPO}/protocols/printers/'),
    ]
    if waveforms:
        changes += [("waveforms = false", "waveforms = true"), ('signal = "features"', 'signal = "waveforms"')]
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new, 1)
    protocol = tmp / f"{name}.toml"
    protocol.write_text(text)
    out = tmp / name
    assert main(["campaign", "run", str(protocol), "--dry-run", "--out", str(out), "--no-report", "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("cutplots")
    return {"features": _paper_like(tmp, "features", False), "waveforms": _paper_like(tmp, "waveforms", True)}


def _row_cut(folder: Path) -> np.ndarray:
    df = read_presses(folder)
    row = df[df["press_id"] == PRESS].iloc[0]
    r = row[[c for c in df.columns if c.startswith("R_ohm_")]].to_numpy(float)
    return ~np.isfinite(r)


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


@pytest.mark.parametrize("source", ["features", "waveforms"])
def test_the_cut_pairs_are_counted_in_the_title_and_nothing_warns(runs, source, tmp_path, capsys):
    folder = runs[source]
    cut = _row_cut(folder)
    assert cut.sum() == 7  # the scene cuts 7 of the 28 pairs on this press (the negative case below: press 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inf - inf warned in press_series and in the largest-change ranking
        s = press_series(folder, PRESS)
        assert main(["dataset", "plot", str(folder), "--press", str(PRESS), "-o", str(tmp_path)]) == 0
    assert "RuntimeWarning" not in capsys.readouterr().err
    assert s.source == source
    np.testing.assert_array_equal(s.cut, cut)
    title = press_title(s, s.cut)
    assert re.search(r"7 of the 28 pairs cut off by the press \(R = inf in its row.*marked 'cut' at the top", title)
    assert _png_size(tmp_path / f"press-{PRESS}.png") == (900, 650)
    # a press that cut nothing says nothing of cuts
    clean = press_series(folder, 2)
    assert not clean.cut.any() and "cut" not in press_title(clean, clean.cut)


def test_the_schematics_cut_pairs_are_marked_at_the_top_over_the_pressed_step(runs):
    import matplotlib.pyplot as plt

    s = press_series(runs["features"], PRESS)
    # the schematic: a cut pair has no baseline in its row (NaN) and an infinite pressed value
    assert np.isnan(s.resistance_ohm[[0, 1, 4, 5]][:, s.cut]).all()
    assert np.isposinf(s.resistance_ohm[[2, 3]][:, s.cut]).all()
    is_open = open_points(s.resistance_ohm, s.cut)
    assert is_open[:, s.cut][[2, 3]].all() and is_open.sum() == 2 * 7
    fig, ax = plt.subplots()
    ax.plot(s.time_s, np.where(is_open, np.nan, s.resistance_ohm))
    _mark_cut(ax, s, s.cut, is_open)
    marks = [line for line in ax.get_lines() if str(line.get_label()).startswith("cut:")]
    assert len(marks) == 1 and marks[0].get_label() == "cut: R = inf (7 pairs, at the top)"
    np.testing.assert_array_equal(marks[0].get_xdata(), [s.onset_s, s.offset_s])  # the pressed step
    np.testing.assert_array_equal(marks[0].get_ydata(), [0.96, 0.96])  # axes fraction: the top
    cut_names = [p for p, c in zip(s.pairs, s.cut) if c]
    texts = [t.get_text() for t in ax.texts]
    assert f"cut (7): {', '.join(cut_names)}" in texts
    plt.close(fig)


def test_a_recorded_cut_pair_reads_open_during_the_press_and_is_not_on_the_r_scale(runs):
    s = press_series(runs["waveforms"], PRESS)
    is_open = open_points(s.resistance_ohm, s.cut)
    assert not is_open[:, ~s.cut].any()  # only cut pairs, and only where they read open
    open_times = s.time_s[is_open.any(axis=1)]
    assert len(open_times) >= 3 and s.onset_s <= open_times.min() and open_times.max() <= s.offset_s
    first = s.resistance_ohm[0]
    assert (s.resistance_ohm[is_open] > OPEN_FOLD * np.broadcast_to(first, s.resistance_ohm.shape)[is_open]).all()
    # what stays on the R scale is the pairs' finite ohms (the cut pairs' before and after the press)
    drawn = np.where(is_open, np.nan, s.resistance_ohm)
    assert np.nanmax(drawn) < 20_000 < np.min(s.resistance_ohm[is_open])


def test_the_largest_changes_rank_only_uncut_pairs_from_finite_points():
    r = np.array(
        [
            [100.0, 200.0, np.nan, 300.0, 50.0],
            [150.0, 260.0, np.inf, 900.0, 50.0],
            [100.0, 200.0, np.nan, 300.0, 52.0],
        ]
    )
    cut = np.array([False, False, True, True, False])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert largest_changes(r, cut, count=5) == [1, 0, 4]  # changes 60, 50, 2; the cut pairs 2 and 3 left out
        assert largest_changes(r, np.zeros(5, bool), count=2) == [3, 1]  # 600 (finite), 60; pair 2: inf only
        assert largest_changes(np.full((2, 3), np.nan), np.zeros(3, bool)) == []

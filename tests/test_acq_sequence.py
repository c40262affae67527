"""The switching sequence: each pair once, never two at once, break-before-make, checked sample by sample."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.acquisition.sequence import SweepTiming, build_sweep, check_sweep, visiting_order
from neatskin.acquisition.wiring import load_wiring
from neatskin.errors import ConfigError

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"


@pytest.fixture(scope="module")
def wiring(paper_layout):
    return load_wiring(PAPER, paper_layout)


@pytest.mark.parametrize("order", ["pairs", "gray"])
def test_paper_sweep_sample_by_sample(wiring, order):
    sweep = build_sweep(wiring, SweepTiming(), order)
    lines = sweep.lines
    assert lines.shape == (28 * (2 + 20 + 100), 9) and sweep.duration_s == pytest.approx(0.3416)
    inhibit = lines[:, 2:]
    addr = lines[:, 0].astype(int) + 2 * lines[:, 1].astype(int)
    enabled = ~inhibit
    # never two chips (two pairs) at once
    assert enabled.sum(axis=1).max() == 1
    # the live pair on each sample is the one its enabled chip and the address route
    on = np.flatnonzero(enabled.any(axis=1))
    chip_on = enabled[on].argmax(axis=1)
    pair_by_lines = {(r.chip, r.address): r.pair_index for r in wiring.routes}
    expected = np.array([pair_by_lines[(c, a)] for c, a in zip(chip_on, addr[on])])
    assert np.array_equal(sweep.pair_of_sample[on], expected)
    assert np.all(sweep.pair_of_sample[~enabled.any(axis=1)] == -1)
    # break-before-make: every address edge has every chip inhibited on that sample and the one before
    prev = np.roll(np.arange(len(lines)), 1)
    edges = np.flatnonzero(addr != addr[prev])
    assert edges.size > 0
    assert inhibit[edges].all() and inhibit[prev[edges]].all()
    # each pair connected in one stretch of settle + live samples, once per sweep
    counts = np.bincount(sweep.pair_of_sample[on], minlength=28)
    assert np.all(counts == 120)
    assert sorted(sweep.order.tolist()) == list(range(28))
    # windows: settle immediately precedes live, live is 100 samples on that pair
    assert np.all(sweep.settle_windows[:, 1] == sweep.live_windows[:, 0])
    assert np.all(np.diff(sweep.live_windows, axis=1) == 100)
    assert np.all(np.diff(sweep.settle_windows, axis=1) == 20)
    for p in range(28):
        a, b = sweep.settle_windows[p, 0], sweep.live_windows[p, 1]
        assert np.all(sweep.pair_of_sample[a:b] == p)
        assert sweep.pair_of_sample[a - 1] == -1
    assert check_sweep(sweep) == []


def test_pairs_order_is_layout_order_and_first_window(wiring):
    sweep = build_sweep(wiring)
    assert sweep.order.tolist() == list(range(28))
    assert sweep.settle_windows[0].tolist() == [2, 22]
    assert sweep.live_windows[0].tolist() == [22, 122]
    assert sweep.live_windows[27].tolist() == [27 * 122 + 22, 28 * 122]


def test_gray_order_saves_line_edges(wiring):
    plain, gray = build_sweep(wiring, order="pairs"), build_sweep(wiring, order="gray")
    # 56 inhibit edges either way; address edges: 6 per chip (0-1-2-3-0) = 42 vs one per switch inside a chip
    # and none between chips (21) plus one on the wrap to the next sweep
    assert plain.line_transitions() == 56 + 42
    assert gray.line_transitions() == 56 + 22
    assert gray.order[:8].tolist() == [0, 1, 3, 2, 6, 7, 5, 4]


def test_check_sweep_catches_violations(wiring):
    sweep = build_sweep(wiring)
    bad = sweep.lines.copy()
    bad[50, 3] = False  # enable a second chip while chip 0 is live
    from dataclasses import replace

    assert any("two chips" in s for s in check_sweep(replace(sweep, lines=bad)))
    bad = sweep.lines.copy()
    bad[121, 0] = not bad[121, 0]  # address edge while pair 0 is still live
    assert any("address changes" in s for s in check_sweep(replace(sweep, lines=bad)))


@settings(max_examples=25, deadline=None)
@given(
    settle=st.integers(0, 30), live=st.integers(1, 60), brk=st.integers(2, 5), order=st.sampled_from(["pairs", "gray"])
)
def test_any_timing_is_sound(wiring, settle, live, brk, order):
    sweep = build_sweep(wiring, SweepTiming(10_000.0, settle, live, brk), order)
    assert check_sweep(sweep) == []
    assert sweep.n_samples == 28 * (settle + live + brk)
    assert np.all(np.diff(sweep.live_windows, axis=1) == live)


def test_bad_timing_refused():
    with pytest.raises(ConfigError, match="break_samples must be an integer >= 2"):
        SweepTiming(break_samples=1)
    with pytest.raises(ConfigError, match="live_samples"):
        SweepTiming(live_samples=0)
    with pytest.raises(ConfigError, match="unknown sweep order"):
        visiting_order(None, "random")

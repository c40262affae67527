"""The paper's pairing (neatskin.baselines.paperpairing) and the paper-like fit's reading noise: selection by the lowest
MSE, a fixed test set, validation rows redrawn per network and disjoint from the test, the noise of the DAQ model."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from neatskin.baselines.paperpairing import (
    NetworkScore,
    fixed_test_rows,
    n_validation_rows,
    pairing_statistics,
    select_best,
    train_networks,
)
from neatskin.errors import DataError
from neatskin.rig.protocol import load_protocol
from neatskin.rig.simcampaign import pair_noise_std_ohm

REPO = Path(__file__).resolve().parent.parent


def _score(mean_mm: float, mse: float, val_mse: float, within: float = 0.5) -> NetworkScore:
    return NetworkScore(mean_mm, within, mse, val_mse, np.arange(3))


# network 0: the lowest mean error; 1: the lowest test MSE; 2: the lowest validation MSE
SCORES = [_score(1.50, 3.0, 0.9, 0.9), _score(1.80, 2.0, 0.8, 0.7), _score(2.10, 4.0, 0.5, 0.4)]


def test_the_best_network_is_the_lowest_test_mse_not_the_lowest_mean_error():
    assert select_best(SCORES, "test") == 1
    assert select_best(SCORES, "validation") == 2
    stats = pairing_statistics(SCORES)
    assert stats["best_mean_mm"] == 1.80 and stats["best_mse_coord_mm2"] == 2.0 and stats["best_within"] == 0.7
    assert stats["bestval_mean_mm"] == 2.10 and stats["bestval_within"] == 0.4
    assert stats["avg_mean_mm"] == pytest.approx(1.80)
    assert stats["avg_mse_coord_mm2"] == pytest.approx(3.0)
    # the std over the networks with ddof 1: deviations -0.3, 0, 0.3 -> sqrt(0.18 / 2) = 0.3
    assert stats["avg_mean_std_mm"] == pytest.approx(0.3)


@given(st.lists(st.tuples(*[st.floats(0.1, 10.0)] * 3), min_size=2, max_size=12, unique_by=lambda t: (t[1], t[2])))
def test_the_selected_network_has_the_lowest_mse_of_its_kind(rows):
    scores = [_score(m, mse, val) for m, mse, val in rows]
    stats = pairing_statistics(scores)
    test_mse = [s.mse_coord_mm2 for s in scores]
    val_mse = [s.val_mse_coord_mm2 for s in scores]
    assert stats["best_mse_coord_mm2"] == min(test_mse)
    assert stats["best_mean_mm"] == scores[test_mse.index(min(test_mse))].mean_mm
    assert stats["bestval_mean_mm"] == scores[val_mse.index(min(val_mse))].mean_mm
    assert min(s.mean_mm for s in scores) <= stats["best_mean_mm"] <= max(s.mean_mm for s in scores)


def test_an_unknown_reading_is_refused():
    with pytest.raises(DataError, match="select_by"):
        select_best(SCORES, "train")
    with pytest.raises(DataError, match="test"):
        fixed_test_rows(np.repeat(np.arange(20), 10), 1, "grouped")


def test_the_test_rows_are_11_positions_x_6_presses_or_2_percent():
    groups = np.repeat(np.arange(100), 28)
    design = fixed_test_rows(groups, 7, "design")
    labels, counts = np.unique(groups[design], return_counts=True)
    assert len(design) == 66 and len(labels) == 11 and set(counts) == {6}
    assert len(fixed_test_rows(groups, 7, "random")) == 56  # 2 % of 2800
    assert n_validation_rows(2800) == 84  # 3 % of 2800


def _toy_campaign(positions: int = 20, repeats: int = 10, seed: int = 0):
    """Features that locate a press: 28 distances to fixed anchors, with a little noise."""
    rng = np.random.default_rng(seed)
    spots = rng.uniform(0, 30, (positions, 2))
    groups = np.repeat(np.arange(positions), repeats)
    xy = spots[groups]
    anchors = rng.uniform(0, 30, (28, 2))
    X = np.hypot(*(xy[:, None, :] - anchors[None]).transpose(2, 0, 1)) + 0.05 * rng.standard_normal((len(xy), 28))
    return X, xy, groups


@pytest.mark.parametrize("test", ["design", "random"])
def test_validation_rows_are_redrawn_per_network_and_disjoint_from_the_fixed_test(test):
    X, xy, groups = _toy_campaign()
    test_idx, scores = train_networks(X, xy, groups, seed=3, networks=3, test=test)
    np.testing.assert_array_equal(test_idx, fixed_test_rows(groups, 3, test))  # fixed: the same for every network
    n_val = n_validation_rows(len(X))
    vals = [np.sort(s.val_rows) for s in scores]
    for val in vals:
        assert len(val) == n_val == len(np.unique(val))
        assert not np.intersect1d(val, test_idx).size  # never a test row
    assert not all(np.array_equal(vals[0], v) for v in vals[1:])  # redrawn: not one validation set for all
    for s in scores:  # the scores are the test rows' and the validation rows': finite, an error in mm
        assert np.isfinite([s.mean_mm, s.mse_coord_mm2, s.val_mse_coord_mm2]).all() and 0 <= s.within <= 1


def test_too_few_presses_for_the_hold_outs_are_refused():
    """One position pressed 7 times: the design takes 6 as test rows, and 1 row cannot both train and validate."""
    X, xy, groups = np.ones((7, 28)), np.zeros((7, 2)), np.zeros(7, dtype=int)
    with pytest.raises(DataError, match="record more presses"):
        train_networks(X, xy, groups, seed=1, networks=1, test="design")


def test_the_fit_reading_noise_is_the_daq_models_at_the_protocols_current_and_scales_as_one_over_it():
    protocol = load_protocol(REPO / "protocols" / "paper.toml")
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import fit_paper_like
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    noise = fit_paper_like.reading_noise_ohm()
    np.testing.assert_array_equal(noise, pair_noise_std_ohm(protocol))
    assert protocol.excitation.amplitude_a == 2e-4
    # the DAQ's voltage noise over a current's I R: the ohm std goes as 1 / current (2.5x at 0.2 mA against 0.5)
    at_half_ma = dataclasses.replace(protocol, excitation=dataclasses.replace(protocol.excitation, amplitude_a=5e-4))
    np.testing.assert_allclose(noise / pair_noise_std_ohm(at_half_ma), 2.5, rtol=0.02)
    assert 0.5 < np.median(noise) < 3.0  # ohm, not the 0.1 once assumed


def test_the_fit_generator_draws_that_noise_on_dr():
    """With every spread knob off, a position's dR varies over its repeats by the reading noise alone: its pooled
    variance over the pairs' noise variance is 1 (chi-square over >= 5 x 39 x 28 dof: 4 sigma is 8 %)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import fit_paper_like
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    from neatskin.sim.scene import PAPER_LIKE

    still = PAPER_LIKE | {
        "placement_error_mm": 0.0,
        "depth_jitter_mm": 0.0,
        "temperature_drift_k_per_h": 0.0,
        "evaporation_fraction_per_h": 0.0,
        "hysteresis_fraction": 0.0,
    }
    noise = fit_paper_like.reading_noise_ohm()

    def variance_ratio(noise_ohm: np.ndarray) -> float:
        dr, _, pos_id = fit_paper_like.paper_features(still, seed=5, positions=8, repeats=40, noise_ohm=noise_ohm)
        # a position whose press cuts a pair reads +inf at every repeat (no spread moves it): left out
        kept = [p for p in range(8) if np.isfinite(dr[pos_id == p]).all()]
        assert len(kept) >= 5
        var = np.stack([dr[pos_id == p].var(axis=0, ddof=1) for p in kept])  # (positions, pairs)
        return float((var / noise**2).mean())

    assert abs(variance_ratio(noise) - 1.0) < 0.08
    # negative control: the generator at 0.1 ohm (the old assumption) reads a variance ratio near 0.006
    assert variance_ratio(np.full(28, 0.1)) < 0.02

"""The floors of neatskin.baselines.floors against exact references: no placement error gives 0, one position gives
0, a flat prior gives the placement error's own spread, two positions give the closed-form Bayes error."""

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

from neatskin.baselines import floors
from neatskin.baselines.floors import label_noise_floor, landing_point_bound_mm
from neatskin.baselines.floortext import add_floor_columns, below_label_floor, floors_section, read_floors


def test_no_placement_error_leaves_no_label_floor():
    xy = np.random.default_rng(0).uniform(0, 30, (20, 2))
    floor = label_noise_floor(xy, xy, 0.0)
    assert np.array_equal(floor.mean_mm, np.zeros(20)) and np.array_equal(floor.rms_mm, np.zeros(20))


def test_one_commanded_position_is_known_whatever_lands():
    xy = np.array([[7.0, 11.0]])
    floor = label_noise_floor(xy, xy, 2.0)
    np.testing.assert_allclose([floor.mean_mm[0], floor.rms_mm[0]], 0.0, atol=1e-9)


def test_a_flat_prior_leaves_the_placement_spread():
    """Commanded positions anywhere (a dense flat prior): the landing point is the best guess, so the floor is the
    placement error itself: mean sigma sqrt(pi / 2), RMS sigma sqrt(2)."""
    sigma = 1.0
    g = np.arange(-6.0, 6.0 + 1e-9, 0.2) * sigma
    prior = np.column_stack([a.ravel() for a in np.meshgrid(g, g)])
    commanded = np.zeros((40, 2))
    mean, rms = label_noise_floor(commanded, prior, sigma, draws=64, seed=3).pooled()
    assert mean == pytest.approx(sigma * math.sqrt(math.pi / 2), rel=0.04)
    assert rms == pytest.approx(sigma * math.sqrt(2), rel=0.04)


@pytest.mark.parametrize("distance_mm", [1.0, 2.5, 4.0])
def test_two_positions_by_row_match_the_closed_form_bayes_error(distance_mm):
    """Two commanded positions d apart, split by row: the posterior mean is a tanh(a l / s^2) (a = d / 2), whose
    RMS error is a quadrature; the spatial median of two points is the heavier one, wrong with probability
    Phi(-a / s), so the mean error is d Phi(-a / s)."""
    sigma, a = 1.35, distance_mm / 2
    prior = np.array([[-a, 0.0], [a, 0.0]])
    floor = label_noise_floor(np.repeat(prior, 200, axis=0), prior, sigma, draws=64, seed=5)
    mean, rms = floor.pooled()
    ms, _ = integrate.quad(
        lambda z: (a - a * np.tanh(a * (a + sigma * z) / sigma**2)) ** 2 * stats.norm.pdf(z), -12, 12
    )
    assert rms == pytest.approx(math.sqrt(ms), rel=0.03, abs=0.01)
    assert mean == pytest.approx(distance_mm * stats.norm.cdf(-a / sigma), rel=0.05, abs=0.01)


def test_the_landing_bound_is_the_crb_and_nuisances_never_lower_it():
    rng = np.random.default_rng(2)
    jac = rng.normal(size=(5, 28, 4))
    std = np.full(28, 0.1)
    known = landing_point_bound_mm(jac, std, np.array([0.0, 0.0]))
    fisher = np.einsum("npa,npb->nab", jac[..., :2], jac[..., :2]) / 0.01
    np.testing.assert_allclose(known, np.sqrt(np.trace(np.linalg.inv(fisher), axis1=1, axis2=2)), rtol=1e-10)
    loose = landing_point_bound_mm(jac, std, np.array([0.2, np.inf]))
    assert np.all(loose >= known * (1 - 1e-12)) and np.any(loose > known * 1.01)


def _limit(n=10):
    return pd.DataFrame(
        {
            "landing_bound_mm": np.full(n, 0.05),
            "label_floor_new_positions_mean_mm": np.full(n, 1.6),
            "label_floor_new_positions_rms_mm": np.full(n, 1.8),
            "label_floor_by_row_mean_mm": np.full(n, 1.2),
            "label_floor_by_row_rms_mm": np.full(n, 1.6),
        }
    )


def test_the_memorisation_flag_uses_the_floor_of_its_own_split():
    table = pd.DataFrame(
        {
            "model": ["a", "a", "b"],
            "split": ["grouped", "random", "random"],
            "mean_error_mm": [1.5, 1.1, 1.3],
            "rms_error_mm": [1.7, 1.5, 1.7],  # below the new-positions floor; below, above the by-row floor
        }
    )
    floors = read_floors(_limit())
    out = add_floor_columns(table, floors)
    assert below_label_floor(out).tolist() == [True, True, False]
    np.testing.assert_allclose(out["excess_mean_mm"], [1.5 - 1.6, 1.1 - 1.2, 1.3 - 1.2])
    text = "\n".join(floors_section(out, floors))
    assert "label-noise floor, new positions" in text and "landing-point bound" in text
    assert "| 1.6 | 1.8 |" in text and "| 1.2 | 1.6 |" in text and "| 0.05 |" in text


def test_a_landing_bound_beyond_the_probe_radius_is_given_by_its_median_and_its_count():
    """A press on a channel the probe shuts has an infinite (or, just off it, a huge) landing bound, which holds
    the pooled RMS: the section says at how many positions it exceeds the probe radius and gives the median over
    positions (0.05 x 6, 3e4, inf x 3: 0.05; a bound within the radius everywhere has no such sentence)."""
    limit = _limit().assign(landing_bound_known_skin_mm=np.r_[np.full(7, 0.02), np.full(3, np.inf)])
    limit.loc[7:, "landing_bound_mm"] = np.inf
    floors = read_floors(limit)
    limit.loc[6, "landing_bound_mm"] = 3e4  # huge, finite: beyond the probe radius too
    floors = read_floors(limit)
    assert floors.landing_rms_mm == np.inf and floors.landing_spread[1:] == (4, 10) and floors.landing_infinite == 3
    assert floors.landing_spread[0] == 0.05 and floors.landing_known_skin_spread == (0.02, 3, 10)
    text = "\n".join(floors_section(pd.DataFrame(), floors))
    assert (
        "The landing-point bound exceeds the probe radius at 4 of 10 positions (infinite at 3: a press that shuts "
        "every channel it reaches, around a junction, tells which channels, not where among them); its median over "
        "all 10 positions is 0.05 mm (0.02 mm with this skin's fabrication known), over the 7 where it is finite 0.05 mm."
        in text
    )
    assert "| | inf: infinite where a channel is shut, median below |" in text  # no bare "inf" as an RMS
    assert read_floors(limit, radius_mm=1e5).landing_spread[1:] == (3, 10)  # the radius is the probe's
    assert "exceeds the probe radius" not in "\n".join(floors_section(pd.DataFrame(), read_floors(_limit())))


def test_the_landing_bounds_median_over_all_positions_is_given_beside_its_median_over_the_finite_ones():
    """The median over all positions counts the infinite ones, which lifts it (0.1, 0.2, 0.3, 0.4, 0.5, inf, inf:
    0.4); over the finite ones it is 0.3. Both are said; with no infinite position only the one."""
    limit = _limit().iloc[:7].copy()
    limit["landing_bound_mm"] = [0.1, 0.2, 0.3, 0.4, 0.5, np.inf, np.inf]
    floors = read_floors(limit, radius_mm=0.35)
    assert floors.landing_spread == (0.4, 4, 7) and floors.landing_infinite == 2
    assert floors.landing_finite_median_mm == 0.3
    text = "\n".join(floors_section(pd.DataFrame(), floors))
    assert "its median over all 7 positions is 0.4 mm, over the 5 where it is finite 0.3 mm." in text
    limit["landing_bound_mm"] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    text = "\n".join(floors_section(pd.DataFrame(), read_floors(limit, radius_mm=0.35)))
    assert "its median over all 7 positions is 0.4 mm." in text and "where it is finite" not in text


def test_an_older_physical_limit_has_no_floors():
    assert read_floors(pd.DataFrame({"crb_mm": [0.1]})) is None


@settings(max_examples=12, deadline=None)
@given(std_mm=st.floats(0.05, 4.0), seed=st.integers(0, 10**6))
def test_leaving_out_prior_points_of_negligible_weight_changes_nothing_a_double_holds(std_mm, seed):
    """The floor sums over the prior points whose posterior weight is at least WEIGHT_CUTOFF of the nearest one's;
    with every neighbour (cutoff 0) it is the same to 1e-12 relative, from a placement much finer than the prior's
    spacing to one far coarser (where every neighbour counts)."""
    rng = np.random.default_rng(seed)
    commanded, prior = rng.uniform(0, 30, (12, 2)), rng.uniform(0, 30, (3000, 2))
    cut = label_noise_floor(commanded, prior, std_mm, draws=16, seed=seed)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(floors, "WEIGHT_CUTOFF", 0.0)
        full = label_noise_floor(commanded, prior, std_mm, draws=16, seed=seed)
    np.testing.assert_allclose(cut.mean_mm, full.mean_mm, rtol=1e-12)
    np.testing.assert_allclose(cut.rms_mm, full.rms_mm, rtol=1e-12)

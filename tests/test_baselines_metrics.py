"""Metrics against hand-computed values, Fig. 9 ellipses, the Cramér-Rao bound, and the splits."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.baselines.crb import cramer_rao_bound_mm
from neatskin.baselines.metrics import error_ellipses, position_errors
from neatskin.baselines.splits import grouped_folds, paper_split, split_folds
from neatskin.errors import DataError


def test_position_errors_on_a_tiny_hand_computed_case():
    true = np.array([[0.0, 0.0], [10.0, 10.0], [5.0, 5.0], [1.0, 1.0]])
    pred = np.array([[3.0, 4.0], [10.0, 11.0], [5.0, 5.0], [1.0, 3.75]])
    # errors 5, 1, 0, 2.75 -> mean 2.1875; squares 25, 1, 0, 7.5625
    e = position_errors(true, pred)
    assert e.n == 4
    assert e.mean_error_mm == pytest.approx(2.1875)
    assert e.std_error_mm == pytest.approx(np.sqrt(np.mean((np.array([5, 1, 0, 2.75]) - 2.1875) ** 2)))
    assert e.median_error_mm == pytest.approx((1 + 2.75) / 2)
    assert e.mse_mm2 == pytest.approx(33.5625 / 4)
    assert e.mse_per_coordinate_mm2 == pytest.approx(33.5625 / 8)  # MATLAB mse over 2 x n targets
    assert e.within_probe_share == pytest.approx(3 / 4)  # 2.75 mm exactly counts as within (paper: <=)


def test_error_ellipse_axes_and_centre_on_a_hand_case():
    # position 7: predictions +-2 along a 45 degree line and +-1 across it, around (11, 21)
    u = np.array([1.0, 1.0]) / np.sqrt(2)
    v = np.array([-1.0, 1.0]) / np.sqrt(2)
    centre = np.array([11.0, 21.0])
    pred7 = centre + np.array([2 * u, -2 * u, v, -v])
    pred = np.vstack([pred7, [[0.0, 0.0]]])
    true = np.vstack([np.tile([10.0, 20.0], (4, 1)), [[0.0, 1.0]]])
    ell = error_ellipses(true, pred, np.array([7, 7, 7, 7, 3]))
    assert ell.group.tolist() == [3, 7]
    np.testing.assert_allclose(ell.mean_pred_mm[1], centre)
    # population variances: major (4 + 4) / 4 = 2, minor (1 + 1) / 4 = 0.5
    np.testing.assert_allclose(ell.std_axes_mm[1], [np.sqrt(2.0), np.sqrt(0.5)])
    assert np.isclose(np.tan(ell.angle_rad[1]), 1.0)
    np.testing.assert_allclose(ell.std_axes_mm[0], [0.0, 0.0])
    np.testing.assert_allclose(ell.centre_error_mm, [1.0, np.sqrt(2.0)])
    assert ell.n.tolist() == [1, 4]


def test_crb_of_a_linear_model_equals_the_analytic_value():
    # features f = A @ (x, y) + noise, C = diag(s^2): cov bound = (A^T C^-1 A)^-1
    rng = np.random.default_rng(0)
    a = rng.normal(size=(28, 2))
    std = rng.uniform(0.5, 2.0, 28)
    expected = np.sqrt(np.trace(np.linalg.inv(a.T @ np.diag(std**-2) @ a)))
    jac = np.broadcast_to(a, (5, 28, 2))
    np.testing.assert_allclose(cramer_rao_bound_mm(jac, noise_std=std), expected, rtol=1e-12)
    np.testing.assert_allclose(cramer_rao_bound_mm(jac, noise_cov=np.diag(std**2)), expected, rtol=1e-12)


def test_crb_hand_value_and_correlated_noise():
    jac = np.array([[[1.0, 0.0], [0.0, 2.0]]])
    assert cramer_rao_bound_mm(jac, noise_std=0.1)[0] == pytest.approx(np.sqrt(0.01 + 0.0025))
    # two identical pairs with fully shared noise carry no more than one of them
    jac2 = np.array([[[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    cov = np.array([[1.0, 0.999999, 0], [0.999999, 1.0, 0], [0, 0, 1.0]])
    assert cramer_rao_bound_mm(jac2, noise_cov=cov)[0] == pytest.approx(np.sqrt(2.0), rel=1e-5)


def test_crb_singular_fisher_is_inf_never_nan():
    jac = np.array(
        [
            [[1.0, 0.0], [2.0, 0.0]],  # nothing sees y
            [[0.0, 0.0], [0.0, 0.0]],  # dead position
            [[np.inf, 1.0], [0.0, 1.0]],  # a pair cut off: its row carries nothing
            [[1.0, 0.0], [0.0, 1.0]],
        ]
    )
    bound = cramer_rao_bound_mm(jac, noise_std=np.array([1.0, 1.0]))
    assert not np.isnan(bound).any()
    assert np.isinf(bound[:3]).all()
    assert bound[3] == pytest.approx(np.sqrt(2.0))


@pytest.mark.parametrize("kwargs", [dict(), dict(noise_std=0.0), dict(noise_cov=np.eye(3))])
def test_crb_bad_noise_is_a_data_error(kwargs):
    with pytest.raises(DataError):
        cramer_rao_bound_mm(np.ones((1, 2, 2)), **kwargs)


@settings(max_examples=30, deadline=None)
@given(n_rows=st.integers(50, 5000), seed=st.integers(0, 2**16))
def test_paper_split_reproduces_95_3_2(n_rows, seed):
    train, val, test = paper_split(n_rows, seed)
    assert len(train) + len(val) + len(test) == n_rows
    assert len(np.unique(np.concatenate([train, val, test]))) == n_rows
    assert len(test) == max(1, round(0.02 * n_rows))
    assert len(val) == max(1, round(0.03 * n_rows))


def test_paper_split_on_the_paper_dataset_size():
    train, val, test = paper_split(2800, 0)
    assert (len(train), len(val), len(test)) == (2660, 84, 56)


def test_grouped_folds_never_share_a_position_and_cover_every_row():
    groups = np.repeat(np.arange(37), 6)
    folds = grouped_folds(groups, n_splits=5, random_state=1)
    assert len(folds) == 5
    seen = np.zeros(len(groups), int)
    for train, test in folds:
        assert not set(groups[train]) & set(groups[test])
        seen[test] += 1
    assert (seen == 1).all()


def test_grouped_split_with_too_few_positions_is_a_data_error():
    assert len(grouped_folds(np.array([1, 1, 2, 2]), n_splits=5)) == 2
    with pytest.raises(DataError, match="at least 2 positions"):
        split_folds("grouped", np.zeros(10, int))
    with pytest.raises(DataError, match="unknown split"):
        split_folds("by_row", np.arange(10))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16), k=st.floats(0.01, 100.0))
def test_crb_scales_with_the_noise_and_never_grows_with_more_pairs(seed, k):
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(4, 6, 2))
    std = rng.uniform(0.1, 1.0, 6)
    bound = cramer_rao_bound_mm(jac, noise_std=std)
    np.testing.assert_allclose(cramer_rao_bound_mm(jac, noise_std=k * std), k * bound, rtol=1e-9)
    fewer = cramer_rao_bound_mm(jac[:, :4], noise_std=std[:4])
    assert (bound <= fewer * (1 + 1e-12)).all()

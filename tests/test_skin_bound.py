"""The position bound with nuisance parameters (skin/bound.py): analytic cases, the Schur complement against the
full inverse, the electronics-only limit against neatskin.baselines.crb, and bad input."""

import numpy as np
import pytest

from neatskin.baselines.crb import cramer_rao_bound_mm
from neatskin.skin.bound import bound_map_mm, feature_jacobian, position_bound_mm
from neatskin.skin.model import SkinModel


def test_a_depth_that_masks_x_costs_exactly_its_information():
    """f = (x + d, y, c d) with unit noise: var(x) = 1 + 1 / (c^2 + 1 / s_d^2), var(y) = 1."""
    c = 0.5
    jac = np.array([[[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, c, 0.0]]])
    unknown = position_bound_mm(jac, 1.0, depth_std_mm=np.inf)
    assert unknown[0] == pytest.approx(np.sqrt(1 + 1 / c**2 + 1), rel=1e-12)
    prior = position_bound_mm(jac, 1.0, depth_std_mm=0.4)
    assert prior[0] == pytest.approx(np.sqrt(1 + 1 / (c**2 + 1 / 0.4**2) + 1), rel=1e-12)
    known = position_bound_mm(jac, 1.0)
    assert known[0] == pytest.approx(np.sqrt(2.0), rel=1e-12)
    placed = position_bound_mm(jac, 1.0, placement_std_mm=0.7)
    assert placed[0] == pytest.approx(np.sqrt(2.0 + 2 * 0.49), rel=1e-12)


def test_a_nuisance_nobody_can_tell_from_position_makes_the_bound_infinite():
    jac = np.array([[[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]]])  # only x + d is seen
    assert position_bound_mm(jac, 1.0, depth_std_mm=np.inf)[0] == np.inf
    assert np.isfinite(position_bound_mm(jac, 1.0, depth_std_mm=1.0)[0])


@pytest.fixture(scope="module")
def skin_jacobian(paper_layout):
    skin = SkinModel(paper_layout)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(1, 29, 12), rng.uniform(1, 29, 12)
    return skin, x, y, feature_jacobian(skin, x, y, np.full(12, 3.5))


def test_electronics_only_is_the_baselines_bound(skin_jacobian):
    skin, x, y, jac = skin_jacobian
    std = np.full(28, 0.1)
    ours = position_bound_mm(jac, std)
    theirs = cramer_rao_bound_mm(jac[..., :2], noise_std=std)
    np.testing.assert_allclose(ours, theirs, rtol=1e-9)
    np.testing.assert_allclose(jac[..., :2], skin.jacobian_mm(x, y, np.full(12, 3.5)), rtol=1e-12, atol=1e-12)


def test_schur_complement_is_the_position_block_of_the_full_inverse(skin_jacobian):
    _, _, _, jac = skin_jacobian
    std = np.full(28, 0.1)
    fisher = np.einsum("npa,npb->nab", jac, jac / std[None, :, None] ** 2)
    fisher[:, 2, 2] += 1 / 0.2**2
    fisher[:, 3, 3] += 1 / 0.01**2
    full = np.linalg.inv(fisher)
    expected = np.sqrt(full[:, 0, 0] + full[:, 1, 1])
    got = position_bound_mm(jac, std, depth_std_mm=0.2, drift_std=0.01)
    np.testing.assert_allclose(got, expected, rtol=1e-7)
    assert np.all(got >= position_bound_mm(jac, std) * (1 - 1e-12))  # nuisances never help
    assert np.all(got <= position_bound_mm(jac, std, depth_std_mm=np.inf, drift_std=np.inf) * (1 + 1e-12))


def test_the_drift_column_is_the_press_dr(skin_jacobian):
    skin, x, y, jac = skin_jacobian
    dr = skin.pair_resistance_ohm(x, y, 3.5) - skin.baseline_pair_resistance_ohm
    np.testing.assert_allclose(jac[..., 3], dr, rtol=1e-15)
    scaled = skin.pair_resistance_ohm(x, y, 3.5, resistivity_factor=1 + 1e-6) - skin.baseline_pair_resistance_ohm * (
        1 + 1e-6
    )
    np.testing.assert_allclose((scaled - dr) / 1e-6, dr, rtol=1e-4, atol=1e-6)


def test_bound_map_covers_the_skin(paper_layout):
    skin = SkinModel(paper_layout, fidelity="network")
    x, y, bound = bound_map_mm(skin, (0, 0, 30, 30), 3.5, 0.1, step_mm=5.0, depth_std_mm=0.15)
    assert bound.shape == (7, 7) and x.tolist() == [0, 5, 10, 15, 20, 25, 30]
    assert np.all(bound > 0)


@pytest.mark.parametrize("kwargs", [{"depth_std_mm": -1.0}, {"drift_std": float("nan")}])
def test_bad_priors_are_refused(skin_jacobian, kwargs):
    with pytest.raises(ValueError, match=">= 0"):
        position_bound_mm(skin_jacobian[3], 0.1, **kwargs)
    with pytest.raises(ValueError, match="noise_std_ohm"):
        position_bound_mm(skin_jacobian[3], 0.0)


def test_a_pair_beyond_what_the_daq_reads_carries_no_information(paper_layout):
    """A reading that clips (R above the compliance or the AI's reach) is masked exactly where a stencil point
    of the pair passes the limit, and nowhere else; with no limit nothing finite is masked."""
    skin = SkinModel(paper_layout)
    x, y, depth = np.array([15.0, 7.5]), np.array([0.5, 7.5]), np.array([3.5, 3.5])
    free = feature_jacobian(skin, x, y, depth)
    assert np.isfinite(free).all()
    pressed = np.asarray(skin.pair_resistance_ohm(x, y, depth), float)
    limit = float(np.median(pressed))  # a limit some pairs of some presses pass
    clipped = feature_jacobian(skin, x, y, depth, max_resistance_ohm=limit)
    masked = np.isnan(clipped).all(axis=-1)
    assert masked[pressed > limit * 1.01].all()  # above the limit at the stencil's centre: masked
    assert not masked[pressed < limit * 0.99].any()  # well below it at every stencil point: kept as it was
    np.testing.assert_array_equal(clipped[~masked], free[~masked])

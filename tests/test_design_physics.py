"""The design study's physics: adjoint Jacobians against finite differences of full solves, the Woodbury pressed
resistances against the exact solver, the depth-as-nuisance bound, the per-pair noise against the simulated DAQ."""

import numpy as np
import pytest

from neatskin.baselines.crb import cramer_rao_bound_mm
from neatskin.design import sensitivity
from neatskin.design.bound import PairNoise, bound_mm, fisher, position_information
from neatskin.design.sensitivity import press_jacobian
from neatskin.skin.layouts import grid_layout
from neatskin.skin.model import SkinModel


@pytest.fixture(scope="module")
def paper_grid():
    return grid_layout(3, 3)


@pytest.fixture(scope="module")
def presses():
    rng = np.random.default_rng(3)
    return rng.uniform(0, 30, 40), rng.uniform(0, 30, 40)


def _electrode_pairs(layout):
    pe = layout.pair_electrode_index
    return pe[:, 0], pe[:, 1]


@pytest.mark.parametrize("fidelity", ["deformation", "network"])
def test_adjoint_jacobian_matches_finite_differences_of_full_solves(paper_grid, presses, fidelity):
    x, y = presses
    model = SkinModel(paper_grid, fidelity=fidelity)
    pj = press_jacobian(paper_grid, paper_grid.electrode_junctions, x, y, 3.5, 2.75, fidelity)
    a, b = _electrode_pairs(paper_grid)
    jac = pj.pair_jacobian(a, b)
    reference = model.jacobian_mm(x, y, 3.5)  # central differences of full network solves, 0.01 mm step
    scale = np.abs(reference).max()
    assert np.abs(jac[..., :2] - reference).max() < 1e-4 * scale
    h = 1e-4
    d_depth = (model.pair_resistance_ohm(x, y, 3.5 + h) - model.pair_resistance_ohm(x, y, 3.5 - h)) / (2 * h)
    assert np.abs(jac[..., 2] - d_depth).max() < 1e-5 * np.abs(d_depth).max()


def test_woodbury_pressed_resistance_is_the_exact_solvers(paper_grid, presses):
    x, y = presses
    pj = press_jacobian(paper_grid, paper_grid.electrode_junctions, x, y, 3.5, 2.75, "deformation")
    a, b = _electrode_pairs(paper_grid)
    exact = SkinModel(paper_grid).pair_resistance_ohm(x, y, 3.5)
    np.testing.assert_allclose(pj.pressed_pair_ohm(a, b), exact, rtol=1e-12)
    # and the unpressed resistances are the spec's exact rationals: R(1,2) = 17/24 R, R(2,6) = 3/2 R
    r = paper_grid.channel_resistance_ohm[0]
    assert pj.baseline_pair_ohm[0, 1] == pytest.approx(17 / 24 * r, rel=1e-12)
    assert pj.baseline_pair_ohm[1, 5] == pytest.approx(3 / 2 * r, rel=1e-12)


def test_tiles_of_nearby_channels_give_the_same_numbers_as_one_tile(monkeypatch):
    layout = grid_layout(6, 5, pitch_mm=10.0)
    xs, ys = np.meshgrid(np.linspace(0.3, 49.7, 13), np.linspace(0.2, 39.9, 11))
    junctions = np.arange(layout.n_junctions)
    tiled = press_jacobian(layout, junctions, xs.ravel(), ys.ravel(), 3.0, 2.0, "deformation")
    monkeypatch.setattr(sensitivity, "TILE_PRESSES", 10_000)
    whole = press_jacobian(layout, junctions, xs.ravel(), ys.ravel(), 3.0, 2.0, "deformation")
    a, b = np.triu_indices(layout.n_junctions, 1)
    np.testing.assert_allclose(tiled.pair_jacobian(a, b), whole.pair_jacobian(a, b), rtol=1e-10, atol=1e-12)


def test_bound_with_known_depth_is_the_baselines_crb_and_nuisance_never_lowers_it(paper_grid, presses):
    x, y = presses
    pj = press_jacobian(paper_grid, paper_grid.electrode_junctions, x, y, 3.5, 2.75, "deformation")
    a, b = _electrode_pairs(paper_grid)
    jac = pj.pair_jacobian(a, b)
    sigma = PairNoise().std(pj.baseline_pair_ohm[a, b])
    info = fisher(jac, sigma)
    known = bound_mm(position_information(info, depth_known=True))
    np.testing.assert_allclose(known, cramer_rao_bound_mm(jac[..., :2], noise_std=sigma), rtol=1e-9)
    nuisance = bound_mm(position_information(info))
    assert np.all(nuisance >= known * (1 - 1e-12))
    assert np.any(nuisance > 1.5 * known)  # depth really is confounded with position somewhere


def test_nuisance_schur_complement_is_the_position_block_of_the_inverse():
    rng = np.random.default_rng(1)
    j = rng.normal(size=(5, 12, 3))
    info = np.einsum("npa,npb->nab", j, j)
    expected = np.sqrt(np.trace(np.linalg.inv(info)[:, :2, :2], axis1=1, axis2=2))
    np.testing.assert_allclose(bound_mm(position_information(info)), expected, rtol=1e-12)


def test_lockin_noise_is_the_simulated_daqs_estimator_std():
    from neatskin.acquisition.daq.base import DaqConfig
    from neatskin.acquisition.sequence import SweepTiming
    from neatskin.design.evaluate import pair_noise
    from neatskin.design.study import Study
    from neatskin.sim.daq import NoiseModel, estimator_moments

    config = DaqConfig()
    noise = NoiseModel()

    class _Sweep:  # estimator_moments reads only the timing for the lock-in method
        timing = SweepTiming()

    r = np.array([[1000.0, 3750.0, 5625.0]])
    _, std, _ = estimator_moments(r, _Sweep(), config, noise, "lockin")
    ours = pair_noise(Study(name="t", source="<t>", amplitude_a=config.amplitude_a)).std(r[0])  # the same current
    np.testing.assert_allclose(ours, std[0], rtol=1e-12)


def test_model_inversion_attains_the_bound_where_the_bound_is_small(paper_grid):
    """The maximum-likelihood inversion is efficient at high SNR: its RMS error over noise draws meets the
    Cramér-Rao bound (depth unknown) - a check of the bound, the Jacobian and the inversion against each other."""
    from neatskin.design.evaluate import pair_noise, press_grid_mm
    from neatskin.design.inversion import InversionSpec, inversion_errors_mm
    from neatskin.design.sensitivity import grounded_inverse
    from neatskin.design.study import Study

    x, y = press_grid_mm(paper_grid, 10)
    noise = pair_noise(Study(name="t", source="<t>", amplitude_a=0.002))  # the paper's 2 mA: the SNR this needs
    pj = press_jacobian(paper_grid, paper_grid.electrode_junctions, x, y, 3.5, 2.75, "deformation")
    a, b = np.triu_indices(8, 1)
    bound = bound_mm(position_information(fisher(pj.pair_jacobian(a, b), noise.std(pj.baseline_pair_ohm[a, b]))))
    errors = inversion_errors_mm(
        paper_grid, paper_grid.electrode_junctions, x, y, 3.5, 2.75, "deformation", noise,
        grounded_inverse(paper_grid), InversionSpec(True, draws=16), seed=0,
    )  # fmt: skip
    assert errors.shape == (16, 100)
    sharp = bound < 0.02  # 80 of the 100 presses on this grid
    assert sharp.sum() == 80
    rms_error = np.sqrt(np.mean(errors[:, sharp] ** 2))
    rms_bound = np.sqrt(np.mean(bound[sharp] ** 2))
    assert rms_error == pytest.approx(rms_bound, rel=0.1)

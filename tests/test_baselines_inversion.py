"""The physics inversion's default solver against the solver it replaced (method="reference"), on the same presses."""

from pathlib import Path

import numpy as np
import pytest

from neatskin.baselines.inversion import invert_presses, skin_inversion
from neatskin.layout import load_layout
from neatskin.skin.model import SkinModel

PAPER_SKIN = Path(__file__).resolve().parent.parent / "protocols" / "skins" / "paper.toml"


def _presses(n: int, placement_sd_mm: float, noise_ohm: float, seed: int):
    """Presses on the paper skin: labelled positions, and dR from positions off by the placement error plus noise."""
    layout = load_layout(PAPER_SKIN)
    skin = SkinModel(layout, fidelity="deformation")
    rng = np.random.default_rng(seed)
    xy = rng.uniform(1.0, 29.0, (n, 2))
    depth = rng.uniform(3.0, 4.0, n)
    at = xy + rng.normal(0.0, placement_sd_mm, xy.shape)
    dr = skin.pair_resistance_ohm(at[:, 0], at[:, 1], depth) - skin.baseline_pair_resistance_ohm
    return layout, xy, dr + rng.normal(0.0, noise_ohm, dr.shape)


@pytest.mark.parametrize(("placement_sd_mm", "noise_ohm"), [(0.0, 0.0), (0.3, 0.5)])
def test_the_batched_solver_lands_where_the_reference_does(placement_sd_mm, noise_ohm):
    layout, xy, dr = _presses(60, placement_sd_mm, noise_ohm, seed=3)
    reference = skin_inversion(layout, dr, method="reference")
    batched = skin_inversion(layout, dr)
    apart = np.hypot(*(batched.xy_mm - reference.xy_mm).T)
    # every press within a few tolerances (1e-5 mm) of the reference's answer but the odd one in a flat
    # valley of the cost, where neither solver has converged and neither fit is better than the other
    assert np.mean(apart < 1e-4) >= 0.95, np.sort(apart)[-5:]
    # a fit as good: the batched solver stops a step under the tolerance earlier, which on noise-free presses
    # leaves up to ~1e-3 ohm (the position 1e-5 mm off) of a residual the reference takes to ~1e-6 (the dry
    # run's noise is ~0.5 ohm)
    assert np.all(batched.residual_ohm <= reference.residual_ohm * 1.02 + 1e-3)
    err_batched = np.hypot(*(batched.xy_mm - xy).T)
    err_reference = np.hypot(*(reference.xy_mm - xy).T)
    assert np.mean(err_batched) == pytest.approx(np.mean(err_reference), abs=0.02)
    # the saving is in model evaluations: a rejected step reuses its Jacobian, a converged press stops
    assert batched.n_model_evaluations < reference.n_model_evaluations


def test_noise_free_presses_come_back_exact_from_either_solver():
    layout, xy, dr = _presses(30, 0.0, 0.0, seed=5)
    for method in ("batched", "reference"):
        err = np.hypot(*(skin_inversion(layout, dr, method=method).xy_mm - xy).T)
        assert np.median(err) < 1e-4, (method, np.sort(err))


def test_a_press_that_shuts_a_channel_inverts_to_finite_numbers():
    # the stiff case: a full-depth press on a channel pinches it shut (an infinite model resistance nearby)
    layout = load_layout(PAPER_SKIN)
    skin = SkinModel(layout, fidelity="deformation")
    dr = skin.pair_resistance_ohm(np.array([7.5]), np.array([0.0]), np.array([0.95 * layout.thickness_mm]))
    dr = np.where(np.isfinite(dr), dr - skin.baseline_pair_resistance_ohm, 1e9)
    res = invert_presses(skin, dr, (0.0, 0.0, 30.0, 30.0), (0.2, 5.2))
    assert np.all(np.isfinite(res.xy_mm)) and np.all(np.isfinite(res.residual_ohm))


def test_an_unknown_method_is_refused():
    layout, _, dr = _presses(2, 0.0, 0.0, seed=1)
    with pytest.raises(ValueError, match="method"):
        skin_inversion(layout, dr, method="newton")

"""SkinModel: the contract the rig uses (baseline, presses, force, Jacobian) and the optional rig effects."""

from __future__ import annotations

import numpy as np
import pytest

from neatskin.layout import ElectrodePair
from neatskin.skin.model import SkinModel, placement_error_mm


@pytest.fixture(scope="module")
def model(paper_layout):
    return SkinModel(paper_layout)


def test_baseline_is_the_exact_rationals_times_pouillet(model, paper_layout):
    r_channel = 0.5 * 0.015 / (2e-3 * 1e-3)  # rho L / A = 3750 ohm
    base = model.baseline_pair_resistance_ohm
    assert base.shape == (28,)
    fractions = {(1, 2): 17 / 24, (1, 3): 5 / 6, (1, 4): 29 / 24, (1, 5): 1.0, (2, 4): 5 / 4, (2, 6): 3 / 2}
    for pair, frac in fractions.items():
        assert base[paper_layout.pairs.index(ElectrodePair(*pair))] == pytest.approx(frac * r_channel, rel=1e-12)


def test_not_touching_gives_baseline_and_shapes(model):
    r = model.pair_resistance_ohm([7.5, 20.0, 3.0], [0.0, 20.0, 3.0], [0.0, -2.0, -0.1])
    assert r.shape == (3, 28)
    assert np.array_equal(r, np.tile(model.baseline_pair_resistance_ohm, (3, 1)))
    assert model.channel_resistance_ohm(1.0, 2.0, 3.5).shape == (1, 12)


def test_press_on_a_channel_raises_its_adjacent_pair_most(model, paper_layout):
    # on channel J00-J10 between electrodes 8 and 1: pair (1,8) is the one that moves most
    dr = model.pair_resistance_ohm(7.5, 0.0, 3.5)[0] - model.baseline_pair_resistance_ohm
    assert paper_layout.pairs[int(np.argmax(dr))] == ElectrodePair(1, 8)
    assert np.all(dr >= 0)  # Rayleigh: pinching never lowers any R_eq


def test_deep_corner_press_cuts_off_electrode_2(model, paper_layout):
    r = model.pair_resistance_ohm(30.0, 0.0, paper_layout.thickness_mm)[0]
    with_2 = np.array([2 in (p.i, p.j) for p in paper_layout.pairs])
    assert np.all(np.isposinf(r[with_2]))
    assert np.all(np.isfinite(r[~with_2]))


def test_network_fidelity_error_against_deformation_is_as_documented(paper_layout, model):
    coarse = SkinModel(paper_layout, fidelity="network")
    grid = np.arange(0.0, 30.01, 1.0)
    x, y = (v.ravel() for v in np.meshgrid(grid, grid))
    depth = np.full(x.size, 3.5)
    base = model.baseline_pair_resistance_ohm
    dr = model.pair_resistance_ohm(x, y, depth) - base
    dr_net = coarse.pair_resistance_ohm(x, y, depth) - base
    scale = np.max(np.abs(dr))
    rms = np.sqrt(np.mean((dr_net - dr) ** 2)) / scale
    # docs/skin.md: rms error ~6 % of the largest change, worst ~50 %, correlation > 0.95
    assert 0.02 < rms < 0.08
    assert np.max(np.abs(dr_net - dr)) / scale < 0.6
    assert np.corrcoef(dr.ravel(), dr_net.ravel())[0, 1] > 0.95


def test_contact_force_formula(model):
    f = model.contact_force_n([-1.0, 0.0, 1.75, 3.5])
    ratio = 2.75 / 5.5
    kappa = 1 + 1.33 * ratio + 1.33 * ratio**3
    expected = 2 * 2.75e-3 * 70e3 * 3.5e-3 / (1 - 0.49**2) * kappa
    assert f[3] == pytest.approx(expected, rel=1e-12)
    assert 2.0 < f[3] < 5.0  # "a couple of newtons"
    assert f[0] == 0.0 and f[1] == 0.0 and f[2] == pytest.approx(f[3] / 2, rel=1e-12)


def test_jacobian_symmetry_and_consistency(model, paper_layout):
    k15 = paper_layout.pairs.index(ElectrodePair(1, 5))
    k23, k78 = paper_layout.pairs.index(ElectrodePair(2, 3)), paper_layout.pairs.index(ElectrodePair(7, 8))
    jac = model.jacobian_mm([15.0, 5.0], [7.5, 1.0], [3.5, 3.5])
    assert jac.shape == (2, 28, 2)
    # the mirror x -> 30 - x fixes electrodes 1 and 5: R_15 is even in x about x = 15, so its
    # x-derivative vanishes there; it swaps (2,3) and (7,8): same d/dy, opposite d/dx
    assert abs(jac[0, k15, 0]) < 1e-9 * np.max(np.abs(jac[0]))
    assert jac[0, k23, 1] == pytest.approx(jac[0, k78, 1], rel=1e-9)
    assert jac[0, k23, 0] == pytest.approx(-jac[0, k78, 0], rel=1e-9)
    assert abs(jac[0, k23, 0]) > 1e-3 * np.max(np.abs(jac[0]))

    # the x-derivative agrees with a secant over a wider step
    r_plus, r_minus = model.pair_resistance_ohm([5.1, 4.9], [1.0, 1.0], [3.5, 3.5])
    assert jac[1, :, 0] == pytest.approx((r_plus - r_minus) / 0.2, rel=2e-3, abs=1e-6 * np.max(np.abs(jac[1])))


def test_jacobian_is_nan_where_cut(model, paper_layout):
    jac = model.jacobian_mm(30.0, 0.0, paper_layout.thickness_mm)
    with_2 = np.array([2 in (p.i, p.j) for p in paper_layout.pairs])
    assert np.all(np.isnan(jac[0, with_2])) and np.all(np.isfinite(jac[0, ~with_2]))


def test_temperature_drift_scales_every_resistance(paper_layout, model):
    warm = SkinModel(paper_layout, temperature_c=26.0)  # 1 K above the reference: -2 %
    assert warm.baseline_pair_resistance_ohm == pytest.approx(0.98 * model.baseline_pair_resistance_ohm, rel=1e-12)
    per_press = model.pair_resistance_ohm([7.5, 7.5], [0.0, 0.0], [3.5, 3.5], temperature_c=[25.0, 30.0])
    assert per_press[1] == pytest.approx(0.9 * per_press[0], rel=1e-12)


def test_placement_error_is_seeded_and_off_by_default(paper_layout):
    x, y = np.full(20000, 10.0), np.full(20000, 5.0)
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    x0, y0 = SkinModel(paper_layout).placement_error_mm(x, y, rng)
    assert np.array_equal(x0, x) and np.array_equal(y0, y) and rng.bit_generator.state == state
    x1, y1 = placement_error_mm(x, y, 0.3, np.random.default_rng(5))
    x2, y2 = placement_error_mm(x, y, 0.3, np.random.default_rng(5))
    assert np.array_equal(x1, x2) and np.array_equal(y1, y2)
    assert np.std(x1 - x) == pytest.approx(0.3, rel=0.03) and np.std(y1 - y) == pytest.approx(0.3, rel=0.03)


def test_hysteresis_lags_on_unloading(paper_layout, model):
    sticky = SkinModel(paper_layout, hysteresis_fraction=0.2)
    loading = sticky.pair_resistance_ohm(7.5, 0.0, 2.0)[0]
    unloading = sticky.pair_resistance_ohm(7.5, 0.0, 2.0, peak_depth_mm=3.5)[0]
    as_if = sticky.pair_resistance_ohm(7.5, 0.0, 2.0 + 0.2 * 1.5)[0]
    assert np.array_equal(unloading, as_if) and np.all(unloading >= loading) and np.any(unloading > loading)
    elastic = model.pair_resistance_ohm(7.5, 0.0, 2.0)
    assert np.array_equal(model.pair_resistance_ohm(7.5, 0.0, 2.0, peak_depth_mm=3.5), elastic)
    assert sticky.contact_force_n(2.0, loading=False)[0] == pytest.approx(0.8 * sticky.contact_force_n(2.0)[0])


def test_non_finite_press_is_refused_naming_the_press(model):
    with pytest.raises(ValueError, match=r"depth_mm must be finite; press 1 has depth_mm = nan"):
        model.pair_resistance_ohm([1.0, 2.0], [1.0, 2.0], [3.5, np.nan])
    with pytest.raises(ValueError, match="x_mm"):
        model.channel_resistance_ohm(np.inf, 1.0, 3.5)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"fidelity": "fem"}, "fidelity"),
        ({"probe_radius_mm": 0.0}, "probe_radius_mm"),
        ({"hysteresis_fraction": 1.0}, "hysteresis_fraction"),
        ({"poisson_ratio": 0.5}, "poisson_ratio"),
        ({"temperature_c": 80.0}, "temperature_c"),
        ({"placement_sigma_mm": -1.0}, "placement_sigma_mm"),
    ],
)
def test_bad_model_parameters_are_refused(paper_layout, kwargs, words):
    with pytest.raises(ValueError, match=words):
        SkinModel(paper_layout, **kwargs)

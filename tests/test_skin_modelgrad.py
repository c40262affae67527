"""The skin model's analytic gradient (skin/modelgrad.py) against central differences of the model itself."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from neatskin.layout import load_layout
from neatskin.skin.deformation import _GRADED_FROM_P0, PinchParams, _channel_geometry, resistance_factor
from neatskin.skin.model import SkinModel
from neatskin.skin.modelgrad import factor_and_gradient

PAPER_SKIN = Path(__file__).resolve().parent.parent / "protocols" / "skins" / "paper.toml"
LAYOUT = load_layout(PAPER_SKIN)
STEP_MM = 1e-5


def _central(skin: SkinModel, x, y, depth) -> np.ndarray:
    """d R_eq / d(x, y, depth) by central differences of pair_resistance_ohm, (n, pairs, 3)."""
    columns = []
    for k in range(3):
        shift = np.zeros(3)
        shift[k] = STEP_MM
        up = skin.pair_resistance_ohm(x + shift[0], y + shift[1], depth + shift[2])
        down = skin.pair_resistance_ohm(x - shift[0], y - shift[1], depth - shift[2])
        columns.append((up - down) / (2 * STEP_MM))
    return np.stack(columns, axis=-1)


def _assert_matches_differences(skin: SkinModel, x, y, depth, tolerance: float = 5e-5) -> int:
    """Every press with no channel shut matches; those with one are NaN. Returns how many were shut."""
    resistance, jac = skin.pair_resistance_and_jacobian_ohm(x, y, depth)
    shut = np.any(np.isinf(skin.pinch_factor(x, y, depth)), axis=1)
    assert np.all(np.isnan(resistance[shut])) and np.all(np.isnan(jac[shut]))
    x, y, depth, resistance, jac = (v[~shut] for v in (x, y, depth, resistance, jac))
    np.testing.assert_allclose(resistance, skin.pair_resistance_ohm(x, y, depth), rtol=1e-13)
    fd = _central(skin, x, y, depth)
    # central differences at 1e-5 mm are good to ~1e-6 of the largest derivative (rounding of R_eq ~ 1e4 ohm over
    # 2e-5 mm, and the step's own h^2 error). The analytic gradient is the exact integral's derivative computed by
    # the model's quadrature; the differences see the derivative of the quadrature's error too, which at the
    # default 6 nodes a panel reaches ~5e-4 of an element where the footprint nearly grazes a channel (at 24 nodes
    # both converge to the same derivative: see the test below)
    scale = np.max(np.abs(fd))
    np.testing.assert_allclose(jac, fd, rtol=0, atol=tolerance * scale + 1e-6)
    return int(shut.sum())


def _near_the_panel_switch(x: float, y: float, depth: float, radius_mm: float = 2.75, within: float = 1e-4) -> bool:
    """A channel whose pinch peaks at 0.9 (give or take `within`): a side of it switches between the standard and the
    graded panels there, and the model's value steps by the quadrature's error (differences across it are none)."""
    start, unit, length = _channel_geometry(LAYOUT)
    rel = np.array([x, y]) - start
    along = np.clip(rel[:, 0] * unit[:, 0] + rel[:, 1] * unit[:, 1], 0.0, length)
    gap = np.hypot(rel[:, 0] - along * unit[:, 0], rel[:, 1] - along * unit[:, 1]) - radius_mm
    decay = 0.5 * (LAYOUT.channel_depth_mm + depth)
    peak = depth / LAYOUT.thickness_mm * np.exp(-((np.maximum(gap, 0.0) / decay) ** 2))
    return bool(np.any(np.abs(peak - _GRADED_FROM_P0) < within))


def _near_a_kink(x: float, y: float, radius_mm: float = 2.75, within_mm: float = 1e-3) -> bool:
    """The probe's edge tangent to a channel's line, or its footprint's edge on a channel's end: there the model's
    quadrature error has a square-root kink (its panels start where the footprint meets the channel), so its
    one-sided differences part (measured at (0, 17.75), tangent to y = 15: 0.06428 above, 0.06534 below at 1e-6
    mm, the analytic 0.064277 being the exact integral's) and central differences are no reference."""
    start, unit, length = _channel_geometry(LAYOUT)
    rel = np.array([x, y]) - start
    s0 = rel[:, 0] * unit[:, 0] + rel[:, 1] * unit[:, 1]
    perp = np.abs(rel[:, 0] * unit[:, 1] - rel[:, 1] * unit[:, 0])
    half_chord = np.sqrt(np.maximum(radius_mm**2 - perp**2, 0.0))
    tangent = np.abs(perp - radius_mm) < within_mm
    edges = np.stack([s0 - half_chord, s0 + half_chord], axis=1)
    on_end = (perp < radius_mm)[:, None] & ((np.abs(edges) < within_mm) | (np.abs(edges - length[:, None]) < within_mm))
    return bool(np.any(tangent) or np.any(on_end))


@settings(max_examples=60, deadline=None)
@example(x=0.0, y=27.25390625, depth_fraction=0.25)  # 0.0039 mm inside tangency with y = 30: 6 nodes skipped
@given(
    x=st.floats(-1.0, 31.0),
    y=st.floats(-1.0, 31.0),
    depth_fraction=st.floats(0.02, 0.97),
)
def test_the_gradient_is_the_models_own_central_difference(x, y, depth_fraction):
    assume(not _near_a_kink(x, y))
    # the sides of a channel the pinch peaks on above 0.9 get graded panels; where a peak is 0.9 the model's
    # quadrature switches panels (its value steps by the quadrature's error there), so differences across it are no
    # reference
    depth = depth_fraction * LAYOUT.thickness_mm
    assume(not _near_the_panel_switch(x, y, depth))
    press = (np.array([x]), np.array([y]), np.array([depth]))
    # 24 nodes a panel: the quadrature's error is negligible, and the two agree to the differences' own accuracy
    _assert_matches_differences(SkinModel(LAYOUT, pinch=PinchParams(nodes_per_panel=24)), *press)
    # the default 6: apart by the derivative of the quadrature's error (measured up to 2e-4 of the largest), which
    # grows as 1 / sqrt(depth into the chord) just inside a tangency: 8e-5 / sqrt(gap / mm) of the largest (x = 0,
    # the footprint 0.001 / 0.0039 / 0.01 / 0.1 mm over y = 30: 2.8e-3 / 1.3e-3 / 7.6e-4 / 1.1e-4; 07d1518 alike,
    # found by hypothesis at y = 27.25390625), so this one keeps 0.01 mm off the kinks
    if not _near_a_kink(x, y, within_mm=1e-2):
        _assert_matches_differences(SkinModel(LAYOUT), *press, tolerance=1e-3)


def test_where_the_quadratures_derivative_errs_the_gradient_is_the_converged_one():
    # the footprint's edge 0.125 mm inside the channel y = 30, near its end: at 6 nodes the model's own difference
    # is 5e-4 off the converged derivative, the analytic gradient 7e-5 (both converge by 24 nodes)
    x, y, depth = np.array([0.0]), np.array([27.375]), np.array([0.25 * LAYOUT.thickness_mm])
    converged = _central(SkinModel(LAYOUT, pinch=PinchParams(nodes_per_panel=48)), x, y, depth)
    _, jac = SkinModel(LAYOUT).pair_resistance_and_jacobian_ohm(x, y, depth)
    own = _central(SkinModel(LAYOUT), x, y, depth)
    scale = np.max(np.abs(converged))
    assert np.max(np.abs(jac - converged)) < 0.5 * np.max(np.abs(own - converged))
    assert np.max(np.abs(jac - converged)) < 2e-4 * scale


def test_a_batch_of_presses_on_and_off_the_channels_and_channel_heights():
    rng = np.random.default_rng(4)
    x, y = rng.uniform(-0.5, 30.5, 64), rng.uniform(-0.5, 30.5, 64)
    x[:8], y[:8] = 15.0, np.linspace(0.0, 30.0, 8)  # on the middle vertical channel's centre line, ends included
    depth = np.where(rng.uniform(size=64) < 0.5, 0.95 * LAYOUT.thickness_mm, rng.uniform(0.3, 5.0, 64))
    assert _assert_matches_differences(SkinModel(LAYOUT), x, y, depth) == 0
    heights = tuple(rng.uniform(0.8, 1.2, LAYOUT.n_channels))  # a pinch scale per channel (fabrication spread)
    # a channel 20 % lower shuts under a press to 0.95 of the thickness: those presses are NaN, the rest match
    assert 0 < _assert_matches_differences(SkinModel(LAYOUT, channel_height_factor=heights), x, y, depth) < 32


def test_the_factor_is_the_quadratures_to_rounding():
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-0.5, 30.5, 300), rng.uniform(-0.5, 30.5, 300)
    depth = rng.uniform(0.0, 1.0, 300) * LAYOUT.thickness_mm
    factor, _ = factor_and_gradient(LAYOUT, x, y, depth, 2.75)
    np.testing.assert_allclose(factor, resistance_factor(LAYOUT, x, y, depth, 2.75), rtol=1e-14)


def test_a_stiff_press_nearly_shutting_a_channel_against_differences():
    # p0 = 0.999: the pinched stretch conducts 1000x less than the rest, the integrand a narrow peak at the
    # footprint's edge (graded panels): the gradient still matches the model's own differences
    skin = SkinModel(LAYOUT)
    x, y = np.array([7.5, 15.0, 22.0]), np.array([0.0, 7.5, 15.2])
    _assert_matches_differences(skin, x, y, np.full(3, 0.999 * LAYOUT.thickness_mm))


def test_a_channel_pinched_shut_gives_nan_not_a_wrong_number():
    # pinch gain 2: half the thickness shuts the channels under the probe (F = inf, conductance 0): the value and the
    # gradient of such a press are NaN (the solver differences those rows); a press that shuts nothing is exact
    skin = SkinModel(LAYOUT, pinch=PinchParams(pinch_gain=2.0))
    x, y = np.array([7.5, 7.5]), np.array([0.0, 0.0])
    depth = np.array([0.6, 0.2]) * LAYOUT.thickness_mm
    assert np.isinf(resistance_factor(LAYOUT, x[:1], y[:1], depth[:1], 2.75, skin.pinch)).any()
    assert _assert_matches_differences(skin, x, y, depth) == 1


def test_skins_it_does_not_differentiate_say_so():
    for skin in (SkinModel(LAYOUT, fidelity="network"), SkinModel(LAYOUT, displaced_fluid_fraction=0.5)):
        assert not skin.has_analytic_jacobian
        with pytest.raises(ValueError, match="difference pair_resistance_ohm"):
            skin.pair_resistance_and_jacobian_ohm(10.0, 10.0, 3.0)
    assert SkinModel(LAYOUT).has_analytic_jacobian


def test_sides_batched_to_fit_the_buffers_give_the_same_numbers(monkeypatch):
    """A chunk's sides go in batches that fit the reused buffers (`_BUFFER_MAX`, 6 arrays): many small batches give
    what one does, presses near full depth (graded sides) and shallow ones, with channel heights."""
    import neatskin.skin.modelgrad as modelgrad

    rng = np.random.default_rng(8)
    x, y = rng.uniform(-0.5, 30.5, 200), rng.uniform(-0.5, 30.5, 200)
    depth = rng.uniform(0.2, 0.999, 200) * LAYOUT.thickness_mm
    scale = rng.uniform(0.9, 1.1, LAYOUT.n_channels)
    whole = factor_and_gradient(LAYOUT, x, y, depth, 2.75, PinchParams(), scale)
    monkeypatch.setattr(modelgrad, "_BUFFER_MAX", 6 * 6 * 9 * 50)  # 50 graded sides (9 panels of 6 nodes) a batch
    batched = factor_and_gradient(LAYOUT, x, y, depth, 2.75, PinchParams(), scale)
    np.testing.assert_allclose(batched[0], whole[0], rtol=1e-15)
    np.testing.assert_allclose(batched[1], whole[1], rtol=1e-13, atol=1e-13 * np.nanmax(np.abs(whole[1])))
    np.testing.assert_allclose(whole[0], resistance_factor(LAYOUT, x, y, depth, 2.75, PinchParams(), scale), rtol=1e-14)


def test_the_network_part_is_exact_on_a_ring_of_channels():
    """A 2 x 2 grid is a ring of 4 channels: between two junctions R_eq = A B / (A + B) (A, B the two arcs' sums) and
    dR_eq/dR_c = (B / (A + B))^2 for a channel on arc A, exact rationals (Fractions) for integer factors. 1,000 rows
    (two chunks of the reused temporaries), one in ten with a channel shut (NaN)."""
    from fractions import Fraction

    from neatskin.skin.layouts import grid_layout
    from neatskin.skin.modelgrad import pair_resistance_and_gradient

    ring = grid_layout(2, 2, pitch_mm=15.0)
    order = [0, 1, 3, 2]  # junctions around the ring; channel c joins ring[c] and ring[c + 1]
    arc_channel = {
        frozenset((order[k], order[(k + 1) % 4])): c
        for k in range(4)
        for c in range(4)
        if set(ring.channel_ends[c]) == {order[k], order[(k + 1) % 4]}
    }
    rng = np.random.default_rng(2)
    n = 1000
    factor = rng.integers(1, 6, (n, 4)).astype(float)
    factor[::10, 1] = np.inf
    factor_grad = rng.integers(-3, 4, (n, 4, 3)).astype(float)
    baseline = np.array([3.0, 5.0, 7.0, 11.0])
    r_eq, jac = pair_resistance_and_gradient(ring, factor, factor_grad, baseline)
    assert np.all(np.isnan(r_eq[::10])) and np.all(np.isnan(jac[::10]))
    for row in rng.choice(np.flatnonzero(np.isfinite(factor).all(axis=1)), 40, replace=False):
        ohm = [Fraction(int(baseline[c])) * int(factor[row, c]) for c in range(4)]
        for p, (i, j) in enumerate(ring.pair_electrode_index):
            a, b = order.index(int(ring.electrode_junctions[i])), order.index(int(ring.electrode_junctions[j]))
            lo, hi = min(a, b), max(a, b)
            arc_a = [arc_channel[frozenset((order[k], order[k + 1]))] for k in range(lo, hi)]
            arc_b = [c for c in range(4) if c not in arc_a]
            sum_a, sum_b = sum(ohm[c] for c in arc_a), sum(ohm[c] for c in arc_b)
            total = sum_a + sum_b
            assert r_eq[row, p] == pytest.approx(float(sum_a * sum_b / total), rel=1e-13)
            d_ohm = {c: ((sum_b if c in arc_a else sum_a) / total) ** 2 for c in range(4)}  # dR_eq / dR_c
            expected = [
                float(sum(d_ohm[c] * int(baseline[c]) * int(factor_grad[row, c, k]) for c in range(4)))
                for k in range(3)
            ]
            np.testing.assert_allclose(jac[row, p], expected, rtol=1e-12, atol=1e-12 * float(total))


def test_a_scalar_depth_holds_for_every_press_as_in_the_value():
    """factor_and_gradient broadcasts its inputs as resistance_factor does: a scalar depth is every press's (it once
    applied to the first press only, and the others came back untouched, factor 1)."""
    layout = LAYOUT
    x, y = np.array([7.5, 3.0, 12.0]), np.array([0.0, 0.5, 0.2])
    factor, grad = factor_and_gradient(layout, x, y, 3.0, 2.75)
    np.testing.assert_allclose(factor, resistance_factor(layout, x, y, np.full(3, 3.0), 2.75), rtol=1e-13)
    assert np.all(factor.max(axis=1) > 1.0) and grad.shape == (3, layout.n_channels, 3)

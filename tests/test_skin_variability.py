"""Skin-side variability sources against analytic values or an independent reference: fabrication spread
(lognormal heights, broken symmetry), fluid volume conservation (to rounding; negative dR on far pairs),
drift, viscoelastic dents; and the scene's knobs (presets, overrides, bad values)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from neatskin.skin.deformation import PinchParams, pinch_fraction, pinched_length_fraction
from neatskin.skin.model import SkinModel
from neatskin.skin.variability import (
    MAX_REMEMBERED_PRESSES,
    Relaxation,
    drift_resistivity_factor,
    fabrication_heights,
)


def test_fabrication_heights_are_lognormal_with_the_set_spread():
    heights = np.log(fabrication_heights(20_000, 0.08, seed=5))
    assert abs(heights.std() - 0.08) < 0.08 * 0.03  # 3 % is > 4 standard errors at n = 20,000
    assert abs(heights.mean()) < 0.003
    assert fabrication_heights(12, 0.08, seed=5) == fabrication_heights(12, 0.08, seed=5)
    assert fabrication_heights(12, 0.0, seed=5) is None


def test_fabrication_spread_breaks_the_layouts_symmetry(paper_layout):
    ideal = SkinModel(paper_layout)
    heights = fabrication_heights(paper_layout.n_channels, 0.08, seed=2019)
    spread = SkinModel(paper_layout, channel_height_factor=heights)
    np.testing.assert_array_equal(spread.channel_baseline_ohm, paper_layout.channel_resistance_ohm / np.array(heights))
    index = {p: k for k, p in enumerate(paper_layout.pairs)}
    for members in paper_layout.pair_classes:
        cls = [index[p] for p in members]
        assert np.ptp(ideal.baseline_pair_resistance_ohm[cls]) < 1e-9 * ideal.baseline_pair_resistance_ohm[cls[0]]
        assert np.ptp(spread.baseline_pair_resistance_ohm[cls]) > 1e-3 * spread.baseline_pair_resistance_ohm[cls[0]]


def test_a_shallower_channel_pinches_by_more():
    """Same absolute height lost: a channel at 0.8 of the height, pressed at 0.3 of it, loses 0.375."""
    from neatskin.layout import layout_from_dict

    layout = layout_from_dict(
        {
            "skin": {"name": "one", "thickness_mm": 5.5, "channel_depth_mm": 2.0, "resistivity_ohm_m": 1.0},
            "channel_defaults": {"width_mm": 2.0, "height_mm": 1.0},
            "junctions": [{"name": "a", "x_mm": 0.0, "y_mm": 0.0}, {"name": "b", "x_mm": 15.0, "y_mm": 0.0}],
            "channels": [{"from": "a", "to": "b"}],
            "electrodes": [{"number": 1, "junction": "a"}, {"number": 2, "junction": "b"}],
        }
    )
    depth = 0.3 * 5.5  # p0 = 0.3 under the probe
    nominal = pinched_length_fraction(layout, 7.5, 0.0, depth, 2.75)[0, 0]
    shallow = pinched_length_fraction(layout, 7.5, 0.0, depth, 2.75, pinch_scale=np.array([1 / 0.8]))[0, 0]
    assert shallow / nominal == pytest.approx(1 / 0.8, rel=1e-12)


def test_pinched_volume_matches_quadpack(paper_layout):
    """(1/L) integral of p(r(s)) ds, held against scipy.integrate.quad on a channel the probe sits beside."""
    ch = 0
    a, b = paper_layout.xy_mm[paper_layout.channel_ends[ch]]
    length = float(np.hypot(*(b - a)))
    depth = 3.0  # the probe's centre 4 mm along the channel and 1.5 mm beside it
    x, y = (a + (b - a) * 4.0 / length + np.array([(b - a)[1], -(b - a)[0]]) / length * 1.5).tolist()
    got = pinched_length_fraction(paper_layout, x, y, depth, 2.75)[0, ch]

    def p(s):
        point = a + (b - a) * s / length
        r = math.hypot(point[0] - x, point[1] - y)
        return float(pinch_fraction(r, depth, 2.75, paper_layout.thickness_mm, paper_layout.channel_depth_mm))

    ref, _ = quad(p, 0.0, length, limit=200, epsabs=1e-14, epsrel=1e-13, points=[4.0 - 2.5, 4.0, 4.0 + 2.5])
    assert got == pytest.approx(ref / length, rel=1e-8)  # the default 6 nodes per panel: ~1.5e-9 here
    assert PinchParams().nodes_per_panel == 6


def test_fluid_volume_is_conserved_to_rounding(paper_layout):
    rng = np.random.default_rng(0)
    x, y, depth = rng.uniform(0, 30, 200), rng.uniform(0, 30, 200), rng.uniform(0.5, 4.5, 200)
    sealed = SkinModel(paper_layout, displaced_fluid_fraction=1.0)
    before = sealed.channel_volume_mm3.sum()
    after = sealed.channel_fluid_volume_mm3(x, y, depth).sum(axis=1)
    assert np.max(np.abs(after / before - 1)) < 1e-14
    lost = sealed.pinched_volume_mm3(x, y, depth).sum(axis=1)
    assert lost.min() > 0 and lost.max() > 10  # mm^3: every press displaces fluid, on a channel a lot
    half = SkinModel(paper_layout, displaced_fluid_fraction=0.5)
    after_half = half.channel_fluid_volume_mm3(x, y, depth).sum(axis=1)
    np.testing.assert_allclose(after_half, before - 0.5 * lost, rtol=1e-13)


def test_a_sealed_network_gives_far_pairs_a_negative_dr(paper_layout):
    press = (29.0, 7.5, 3.5)  # on the right edge's lower channel
    open_skin = SkinModel(paper_layout)
    sealed = SkinModel(paper_layout, displaced_fluid_fraction=1.0)
    d_open = open_skin.pair_resistance_ohm(*press)[0] - open_skin.baseline_pair_resistance_ohm
    d_sealed = sealed.pair_resistance_ohm(*press)[0] - sealed.baseline_pair_resistance_ohm
    assert d_open.min() >= -1e-9  # without the fluid's conservation no pair can fall
    assert d_sealed.min() < -1.0  # ohm: the widened far channels conduct better
    # an untouched channel's resistance falls by exactly the widening
    widening = sealed.fluid_widening(*press)[0]
    r_ch = sealed.channel_resistance_ohm(*press)[0]
    far = open_skin.channel_resistance_ohm(*press)[0] == paper_layout.channel_resistance_ohm
    assert far.any()
    np.testing.assert_allclose(r_ch[far], paper_layout.channel_resistance_ohm[far] / widening, rtol=1e-15)


def test_drift_factor_is_the_product_of_temperature_and_evaporation():
    t = np.array([0.0, 1800.0, 7200.0])
    got = drift_resistivity_factor(t, 2.0, 0.01, -0.02)
    np.testing.assert_allclose(got, (1 - 0.04 * t / 3600) * (1 - 0.01 * t / 3600), rtol=1e-15)
    assert drift_resistivity_factor(0.0, 5.0, 0.1) == 1.0


def test_residual_dents_relax_exponentially_in_press_order():
    relax = Relaxation(hysteresis_fraction=0.1, relaxation_time_s=20.0, press_interval_s=8.0)
    commanded = np.column_stack([np.arange(100.0), np.zeros(100), np.full(100, 3.5)])
    dents = relax.residual_dents(10, commanded)
    ages = 10 - dents[:, 0]  # x is the press id here
    np.testing.assert_allclose(dents[:, 2], 0.1 * 3.5 * np.exp(-ages * 8.0 / 20.0), rtol=1e-15)
    assert dents[:, 2].min() > 1e-4 and ages.max() == 10  # all ten earlier presses are still felt
    assert len(relax.residual_dents(0, commanded)) == 0
    assert len(relax.residual_dents(99, commanded)) <= MAX_REMEMBERED_PRESSES
    assert len(relax.residual_dents(99, commanded)) == relax.memory_presses(3.5) == 20


def test_extra_factor_and_resistivity_factor_scale_channels_exactly(paper_layout):
    skin = SkinModel(paper_layout)
    extra = np.linspace(0.0, 0.2, paper_layout.n_channels)
    r = skin.channel_resistance_ohm(0.0, 0.0, 0.0, resistivity_factor=0.97, extra_factor=extra[None])
    np.testing.assert_allclose(r[0], paper_layout.channel_resistance_ohm * (1 + extra) * 0.97, rtol=1e-15)


def test_bad_skin_variability_is_refused(paper_layout):
    with pytest.raises(ValueError, match="channel_height_factor must be 12 positive"):
        SkinModel(paper_layout, channel_height_factor=(1.0,) * 11)
    with pytest.raises(ValueError, match="displaced_fluid_fraction"):
        SkinModel(paper_layout, displaced_fluid_fraction=1.5)

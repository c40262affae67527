"""The deformation integral: exact limits, convergence against an independent adaptive reference,
and the stated error bound of the default resolution."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from neatskin.skin import deformation
from neatskin.skin.deformation import (
    PinchParams,
    factor_and_length_fraction,
    nearest_point_factor,
    pinch_fraction,
    pinched_length_fraction,
    resistance_factor,
)
from neatskin.skin.layouts import grid_layout

PROBE_MM = 2.75


@pytest.fixture(scope="module")
def single():
    """One 15 mm channel along x from (0, 0) to (15, 0) (a 2 x 2 grid is 4 channels; channel 0 is it)."""
    return grid_layout(2, 2, pitch_mm=15.0)


def quad_reference(layout, x, y, depth, params=PinchParams(), volume=False):
    """Adaptive QUADPACK integral of 1 / (1 - p(r(s))) (or of p, volume) over channel 0, split at the kinks."""
    start = layout.xy_mm[layout.channel_ends[0, 0]]
    end = layout.xy_mm[layout.channel_ends[0, 1]]
    length = float(np.hypot(*(end - start)))
    unit = (end - start) / length

    def integrand(s):
        px, py = start + s * unit
        r = np.hypot(x - px, y - py)
        p = pinch_fraction(r, depth, PROBE_MM, layout.thickness_mm, layout.channel_depth_mm, params)
        return p if volume else 1.0 / (1.0 - p)

    s0 = (x - start[0]) * unit[0] + (y - start[1]) * unit[1]
    perp = abs((x - start[0]) * unit[1] - (y - start[1]) * unit[0])
    e = np.sqrt(max(PROBE_MM**2 - perp**2, 0.0))
    cuts = sorted({0.0, length, *(min(max(v, 0.0), length) for v in (s0 - e, s0, s0 + e))})
    total = sum(quad(integrand, lo, hi, epsabs=0, epsrel=1e-13, limit=200)[0] for lo, hi in zip(cuts[:-1], cuts[1:]))
    return total / length


PRESSES = [  # (x, y, depth): on the channel, off it, at its end, near the probe-edge tangent, deep
    (7.5, 0.0, 3.5),
    (7.5, 2.0, 3.5),
    (7.5, 2.9, 3.5),
    (7.5, 4.0, 3.5),
    (0.0, 0.0, 3.5),
    (3.0, 1.0, 3.5),
    (7.5, 7.5, 3.5),
    (-2.0, 1.5, 3.5),
    (16.0, 2.5, 3.5),
    (7.5, 1.0, 1.0),
    (7.5, 1.0, 4.5),
    (7.5, 3.0, 5.0),
]


@pytest.mark.parametrize("x, y, depth", PRESSES)
def test_default_resolution_within_stated_bound_of_adaptive_reference(single, x, y, depth):
    factor = resistance_factor(single, x, y, depth, PROBE_MM)[0, 0]
    # docs/skin.md: the default 6 nodes per panel -> <= 1e-5 relative for depth <= 0.91 T
    assert factor == pytest.approx(quad_reference(single, x, y, depth), rel=1e-5)
    fine = resistance_factor(single, x, y, depth, PROBE_MM, PinchParams(nodes_per_panel=16))[0, 0]
    assert fine == pytest.approx(quad_reference(single, x, y, depth), rel=1e-10)


def test_error_falls_with_resolution_against_fine_reference(paper_layout):
    rng = np.random.default_rng(7)
    n = 400
    x, y = rng.uniform(-3, 33, n), rng.uniform(-3, 33, n)
    depth = rng.uniform(0.5, 5.0, n)
    fine = resistance_factor(paper_layout, x, y, depth, PROBE_MM, PinchParams(nodes_per_panel=48))
    errors = []
    for q in (3, 6, 8, 12):
        approx = resistance_factor(paper_layout, x, y, depth, PROBE_MM, PinchParams(nodes_per_panel=q))
        errors.append(np.max(np.abs(approx / fine - 1)))
    assert errors == sorted(errors, reverse=True)  # monotone convergence
    # the table in docs/skin.md: default 6 nodes <= 1e-5, 8 nodes <= 1e-6, 12 nodes <= 1e-9
    assert errors[1] < 1e-5 and errors[2] < 1e-6 and errors[3] < 1e-9
    assert errors[0] > 1e-4  # and the coarse end is visibly coarser: the check can fail


def test_not_touching_is_exactly_baseline(paper_layout):
    f = resistance_factor(paper_layout, [7.5, 15.0, 3.0], [0.0, 15.0, 3.0], [0.0, -1.0, -0.01], PROBE_MM)
    assert np.array_equal(f, np.ones((3, 12)))


def test_probe_covering_whole_channel_gives_uniform_pinch(single):
    depth = 2.2
    p0 = depth / single.thickness_mm
    f = resistance_factor(single, 7.5, 0.0, depth, 40.0)[0, 0]  # a 40 mm probe covers the 15 mm channel
    assert f == pytest.approx(1.0 / (1.0 - p0), rel=1e-14)


def test_pinched_shut_channel_has_infinite_resistance(single):
    f = resistance_factor(single, 7.5, 0.0, single.thickness_mm, PROBE_MM)[0]
    assert np.isposinf(f[0])
    assert np.all(np.isfinite(f[1:]))  # the other channels are 15 mm away: finite


def test_far_press_leaves_channel_unchanged_and_mirror_presses_agree(single):
    f = resistance_factor(single, [7.5, 7.5, 4.0, 11.0], [60.0, 1.0, 1.2, 1.2], 3.5, PROBE_MM)
    assert f[0, 0] == pytest.approx(1.0, abs=1e-15)
    assert f[2, 0] == pytest.approx(f[3, 0], rel=1e-12)  # mirror about the channel's middle
    assert f[1, 0] > f[2, 0] > 1.0


def test_factor_grows_with_depth(single):
    depth = np.linspace(0.1, 5.0, 30)
    f = resistance_factor(single, 7.5, 1.5, depth, PROBE_MM)[:, 0]
    assert np.all(np.diff(f) > 0)


def test_pinch_profile_values(single):
    t, c = single.thickness_mm, single.channel_depth_mm
    assert pinch_fraction(0.0, 3.5, PROBE_MM, t, c) == pytest.approx(3.5 / 5.5, rel=1e-15)
    assert pinch_fraction(PROBE_MM, 3.5, PROBE_MM, t, c) == pytest.approx(3.5 / 5.5, rel=1e-15)
    decay = 0.5 * (c + 3.5)
    assert pinch_fraction(PROBE_MM + decay, 3.5, PROBE_MM, t, c) == pytest.approx(3.5 / 5.5 / np.e, rel=1e-14)
    assert pinch_fraction(1.0, 9.0, PROBE_MM, t, c) == 1.0  # capped: shut, never more


def test_nearest_point_factor_closed_form(single):
    depth = 3.5
    p0 = depth / single.thickness_mm
    f = nearest_point_factor(single, 7.5, 0.0, depth, PROBE_MM)[0, 0]
    assert f == pytest.approx(1 + (2 * PROBE_MM / 15.0) * (1 / (1 - p0) - 1), rel=1e-14)
    assert np.array_equal(nearest_point_factor(single, 7.5, 0.0, 0.0, PROBE_MM), np.ones((1, 4)))


def test_bad_params_are_refused():
    with pytest.raises(ValueError, match="nodes_per_panel"):
        PinchParams(nodes_per_panel=0)
    with pytest.raises(ValueError, match="pinch_gain"):
        PinchParams(pinch_gain=-1.0)


def test_one_pass_for_factor_and_length_fraction_gives_the_bits_of_two():
    """The dry run's skin asks for both in one quadrature: the same bits as the two calls, for presses off the
    skin, shallow, near full depth (graded panels) and shut, with per-channel heights."""
    layout = grid_layout(3, 3)
    rng = np.random.default_rng(5)
    n = 40
    x = rng.uniform(0, 20, n)
    y = rng.uniform(0, 20, n)
    thickness = layout.thickness_mm
    depth = np.concatenate(
        [
            [-1.0, 0.0, np.nan],
            rng.uniform(0.01, 0.6, n - 6) * thickness,
            [0.97 * thickness, 0.99 * thickness, 1.5 * thickness],
        ]
    )
    channel = layout.channels[0]  # the deep presses on a channel's middle
    a, b = layout.junctions[channel.a], layout.junctions[channel.b]
    x[-3:], y[-3:] = (a.x_mm + b.x_mm) / 2, (a.y_mm + b.y_mm) / 2
    scale = rng.uniform(0.8, 1.25, layout.n_channels)
    for pinch_scale in (None, scale):
        factor, share = factor_and_length_fraction(layout, x, y, depth, 2.75, PinchParams(), pinch_scale)
        expected_factor = resistance_factor(layout, x, y, depth, 2.75, PinchParams(), pinch_scale)
        expected_share = pinched_length_fraction(layout, x, y, depth, 2.75, PinchParams(), pinch_scale)
        np.testing.assert_array_equal(factor, expected_factor)
        np.testing.assert_array_equal(share, expected_share)
        assert np.all(factor[:3] == 1.0) and np.all(share[:3] == 0.0)
        assert np.isinf(factor).any()  # some press shuts a channel


# ---- near full depth: graded panels for the sides the pinch peaks on, the standard ones for the rest ----------------


def _near_full_errors(layout, x, y, depth) -> tuple[float, float]:
    """Relative errors of channel 0's factor and length fraction against QUADPACK (the share's floored at 1e-7 of
    the channel: a far press's share is ~1e-16, rounding)."""
    factor, share = factor_and_length_fraction(layout, x, y, depth, PROBE_MM)
    ref_factor = quad_reference(layout, x, y, depth)
    ref_share = quad_reference(layout, x, y, depth, volume=True)
    return abs(factor[0, 0] / ref_factor - 1), abs(share[0, 0] - ref_share) / max(ref_share, 1e-7)


def _switch_offset_mm(layout, depth) -> float:
    """The channel's distance from the probe axis at which its pinch peaks at exactly _GRADED_FROM_P0 (p0 > 0.9)."""
    p0 = depth / layout.thickness_mm
    decay = 0.5 * (layout.channel_depth_mm + depth)
    return PROBE_MM + decay * float(np.sqrt(np.log(p0 / deformation._GRADED_FROM_P0)))


@settings(max_examples=80, deadline=None)
@given(
    p0=st.floats(0.9, 0.99999, exclude_min=True),
    x=st.floats(-4.0, 19.0),  # along the 15 mm channel, past both ends
    where=st.sampled_from(["anywhere", "grazing", "at the switch"]),
    offset=st.floats(-1.0, 1.0),
)
def test_near_full_presses_within_the_bound_of_quadpack(single, p0, x, where, offset):
    """Presses deeper than 0.9 of the skin, anywhere, with the channel grazing the footprint (perp ~ a, the peak
    spread over the outer panels), or where its peak crosses 0.9 (the side switches panels): both integrals hold
    the ordinary presses' bound (1e-5)."""
    depth = p0 * single.thickness_mm
    y = {"anywhere": 6.0 * offset, "grazing": PROBE_MM + 0.05 * offset}[where] if where != "at the switch" else 0.0
    if where == "at the switch":
        y = _switch_offset_mm(single, depth) + 0.05 * offset
    factor_error, share_error = _near_full_errors(single, x, y, depth)
    assert factor_error < 1e-5 and share_error < 1e-5


@pytest.mark.parametrize("p0", [0.99, 0.999])
@pytest.mark.parametrize("x, y", [(7.5, 0.0), (7.5, 1.0), (-2.0, 1.0), (16.5, 0.5)])
def test_standard_panels_on_every_side_of_a_near_full_press_fail_the_bound(single, monkeypatch, p0, x, y):
    """Negative control: the unsafe shortcut (no side graded) misses the bound for a channel under the probe or
    past its end, where the test above holds it."""
    depth = p0 * single.thickness_mm
    assert _near_full_errors(single, x, y, depth)[0] < 1e-5
    monkeypatch.setattr(deformation, "_GRADED_FROM_P0", 2.0)
    assert _near_full_errors(single, x, y, depth)[0] > 1e-5


def test_a_near_full_press_grades_only_the_sides_it_peaks_on(paper_layout, monkeypatch):
    """A press to 0.95 of the skin on a channel's middle: the channels whose pinch peaks at most 0.9 keep the
    standard panels (the numbers of grading off); the channels under the probe do not."""
    x, y, depth = np.array([7.5, 15.0]), np.array([0.0, 7.5]), np.full(2, 0.95 * paper_layout.thickness_mm)
    graded = resistance_factor(paper_layout, x, y, depth, PROBE_MM)
    monkeypatch.setattr(deformation, "_GRADED_FROM_P0", 2.0)
    standard = resistance_factor(paper_layout, x, y, depth, PROBE_MM)
    start, unit, length = deformation._channel_geometry(paper_layout)
    for k in range(2):
        rel = np.array([x[k], y[k]]) - start
        along = np.clip(rel[:, 0] * unit[:, 0] + rel[:, 1] * unit[:, 1], 0.0, length)
        gap = np.hypot(rel[:, 0] - along * unit[:, 0], rel[:, 1] - along * unit[:, 1]) - PROBE_MM
        decay = 0.5 * (paper_layout.channel_depth_mm + depth[k])
        peak = 0.95 * np.exp(-((np.maximum(gap, 0.0) / decay) ** 2))
        low = peak <= 0.9
        assert 0 < low.sum() < low.size  # both kinds of channel
        # to rounding (the BLAS dot's batches differ); grading every side moves them by up to 3e-10 here
        np.testing.assert_allclose(graded[k, low], standard[k, low], rtol=1e-15)
        assert np.all(np.abs(graded[k, ~low] / standard[k, ~low] - 1) > 1e-7)  # the graded ones: 2.4e-6


@pytest.mark.parametrize("x, y", [(7.5, 0.0), (-2.0, 1.0), (7.5, 2.8)])
def test_a_lower_channel_near_full_is_graded_by_its_own_pinch(single, x, y):
    """Fabrication heights: channel 0 at 0.8 of the others' height loses 1.25 x their pinch, so a press to 0.792 of
    the skin (0.792 for the others, nowhere near full) brings it to p0 = 0.99: its sides are graded by its own p0
    and hold the bound (the reference: the same pinch as a gain of 1.25)."""
    depth = 0.792 * single.thickness_mm
    scale = np.array([1.25, 1.0, 1.0, 1.0])
    factor = resistance_factor(single, x, y, depth, PROBE_MM, pinch_scale=scale)[0, 0]
    assert factor == pytest.approx(quad_reference(single, x, y, depth, PinchParams(pinch_gain=1.25)), rel=1e-5)

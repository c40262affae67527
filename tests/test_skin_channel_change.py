"""Each channel changed in turn by rank-one updates (channelchange.channel_change_delta_ohm) against exact rationals."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_skin_network import exact_pair_resistance

from neatskin.skin import channelchange
from neatskin.skin.channelchange import channel_change_delta_ohm
from neatskin.skin.layouts import grid_layout
from neatskin.skin.maps import paper_sensitivity
from neatskin.skin.network import GROUNDED_MAX_SPREAD, equivalent_resistance


def exact_changes(layout, g: np.ndarray, factor: float) -> list[list[Fraction | None]]:
    """Per channel, per pair: exact R_eq(channel c's resistance times factor) - R_eq(unchanged); None where cut."""
    before = exact_pair_resistance(layout, g)
    out = []
    for c in range(layout.n_channels):
        changed = [Fraction(float(x)) for x in g]
        changed[c] /= Fraction(factor)
        after = exact_pair_resistance(layout, changed)
        out.append([None if a is None or b is None else b - a for a, b in zip(before, after)])
    return out


def _assert_exact(layout, g, factor, delta, *, scale_rtol: float) -> None:
    """Every change within scale_rtol of the exact pair resistance it changes (a few ulps of R_eq)."""
    before = exact_pair_resistance(layout, g)
    for c, row in enumerate(exact_changes(layout, g, factor)):
        for p, exact in enumerate(row):
            if exact is None:
                assert delta[c, p] == 0.0, (c, p, delta[c, p])  # cut before and after: no change, never NaN
                continue
            assert abs(delta[c, p] - float(exact)) <= scale_rtol * float(before[p]), (c, p, delta[c, p], float(exact))


def test_paper_skin_changes_are_exact_and_match_the_full_solve(paper_layout):
    g = 1.0 / paper_layout.channel_resistance_ohm
    delta = channel_change_delta_ohm(paper_layout, g, 1.5)
    assert delta.shape == (12, 28)
    # the rank-one form gives the change itself (no difference of two resistances): exact to ~1e-15 of the change
    for c, row in enumerate(exact_changes(paper_layout, g, 1.5)):
        exact = np.array([float(x) for x in row])  # type: ignore[arg-type]
        np.testing.assert_allclose(delta[c], exact, rtol=1e-12, atol=1e-12 * np.abs(exact).max())
    # the full solve of the 13 states, as paper_sensitivity did before
    states = np.tile(g, (13, 1))
    states[np.arange(1, 13), np.arange(12)] /= 1.5
    r_eq = equivalent_resistance(paper_layout, states)
    np.testing.assert_allclose(delta, r_eq[1:] - r_eq[0], rtol=1e-11, atol=1e-12 * r_eq.max())
    np.testing.assert_array_equal(paper_sensitivity(paper_layout).delta_ohm, delta)


@settings(max_examples=40, deadline=None)
@given(
    spread=st.floats(1.0, GROUNDED_MAX_SPREAD),
    factor=st.floats(0.05, 20.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_rank_one_path_matches_the_full_solve_and_is_rayleigh_monotone_on_a_grid(spread, factor, seed):
    layout = grid_layout(3, 4)
    g = np.exp(np.random.default_rng(seed).uniform(0.0, np.log(spread), layout.n_channels)) * 1e-4
    delta = channel_change_delta_ohm(layout, g, factor)
    # against the GTH full solve of every state (exact to a few ulps of each R_eq; the exact rationals are
    # checked on the paper skin above and on the stiff inputs below, where they are affordable)
    states = np.tile(g, (layout.n_channels + 1, 1))
    states[np.arange(1, layout.n_channels + 1), np.arange(layout.n_channels)] /= factor
    r_eq = equivalent_resistance(layout, states, "dense")
    assert np.all(np.abs(delta - (r_eq[1:] - r_eq[0])) <= 1e-11 * r_eq[0])
    # Rayleigh: raising a resistance never lowers an effective resistance, lowering it never raises one
    assert np.all(delta >= -1e-12 * np.abs(delta).max()) if factor > 1 else np.all(delta <= 1e-12 * np.abs(delta).max())


def test_stiff_inputs_twelve_decades_apart_are_exact(paper_layout):
    rng = np.random.default_rng(7)
    g = 10.0 ** rng.choice([-8.0, -2.0, 4.0], paper_layout.n_channels)  # 1e12 between the extremes
    delta = channel_change_delta_ohm(paper_layout, g, 1.5)
    _assert_exact(paper_layout, g, 1.5, delta, scale_rtol=1e-13)


def test_a_channel_shut_gives_exact_changes_and_zero_on_cut_pairs(paper_layout):
    g = 1.0 / paper_layout.channel_resistance_ohm
    g[0] = 0.0  # pinched shut: one more channel shut would cut an electrode off
    delta = channel_change_delta_ohm(paper_layout, g, 1.5)
    assert np.isfinite(delta).all()
    assert np.all(delta[0] == 0.0)  # scaling a shut channel's resistance changes nothing
    _assert_exact(paper_layout, g, 1.5, delta, scale_rtol=1e-13)
    # an electrode cut off: its pairs are infinite before and after, a change of 0, never NaN
    corner = paper_layout.electrode_junctions[7]
    cut = g.copy()
    cut[(paper_layout.channel_ends == corner).any(axis=1)] = 0.0
    delta_cut = channel_change_delta_ohm(paper_layout, cut, 1.5)
    assert np.isfinite(delta_cut).all()
    _assert_exact(paper_layout, cut, 1.5, delta_cut, scale_rtol=1e-13)


def test_an_unchanged_resistance_changes_nothing_on_both_paths(paper_layout):
    # factor 1 is dg = 0: the rank-one form's denominator R_c f / (f - 1) is infinite, the change exactly 0 (not NaN)
    g = 1.0 / paper_layout.channel_resistance_ohm
    assert np.all(channel_change_delta_ohm(paper_layout, g, 1.0) == 0.0)
    stiff = g * 10.0 ** np.arange(paper_layout.n_channels)  # 1e11 apart: the GTH full solve
    assert np.all(channel_change_delta_ohm(paper_layout, stiff, 1.0) == 0.0)


@pytest.mark.parametrize(
    ("g_fix", "factor", "match"),
    [
        (lambda g: g[:5], 1.5, "shape"),
        (lambda g: -g, 1.5, ">= 0"),
        # a NaN anywhere leaves the sorted order undefined (the ends may be fine): the sum still refuses it
        (lambda g: np.where(np.arange(g.size) == 5, np.nan, g), 1.5, ">= 0"),
        (lambda g: np.where(np.arange(g.size) == 0, np.nan, g), 1.5, ">= 0"),
        (lambda g: np.where(np.arange(g.size) == 7, np.inf, g), 1.5, ">= 0"),
        (lambda g: g, 0.0, "factor"),
        (lambda g: g, np.inf, "factor"),
    ],
)
def test_bad_input_is_refused(paper_layout, g_fix, factor, match):
    with pytest.raises(ValueError, match=match):
        channel_change_delta_ohm(paper_layout, g_fix(1.0 / paper_layout.channel_resistance_ohm), factor)


def test_each_layout_gets_its_own_cached_incidence(paper_layout):
    import gc

    g_paper = 1.0 / paper_layout.channel_resistance_ohm
    first = channel_change_delta_ohm(paper_layout, g_paper, 1.5)
    for size in (3, 4, 3):  # fresh layouts, some collected between calls (an id may be reused)
        layout = grid_layout(size, size)
        g = np.full(layout.n_channels, 1e-3)
        r_eq = equivalent_resistance(layout, np.vstack([g, g * np.where(np.arange(layout.n_channels) == 0, 1 / 2, 1)]))
        np.testing.assert_allclose(channel_change_delta_ohm(layout, g, 2.0)[0], r_eq[1] - r_eq[0], rtol=1e-11)
        del layout
        gc.collect()
    np.testing.assert_array_equal(channel_change_delta_ohm(paper_layout, g_paper, 1.5), first)
    assert channelchange._INCIDENCE[id(paper_layout)][0]() is paper_layout


def test_a_layout_above_the_dense_size_takes_the_full_solve_and_caches_no_rank_one_structure():
    from neatskin.skin import network

    layout = grid_layout(9, 8)  # 72 junctions > DENSE_MAX_JUNCTIONS: no grounded inverse is built for it
    assert layout.n_junctions > network.DENSE_MAX_JUNCTIONS
    g = np.exp(np.random.default_rng(3).uniform(0.0, 2.0, layout.n_channels)) * 1e-4
    delta = channel_change_delta_ohm(layout, g, 1.5)
    assert channelchange._INCIDENCE[id(layout)][1] == (layout.n_channels, None)
    states = np.tile(g, (layout.n_channels + 1, 1))
    states[np.arange(1, layout.n_channels + 1), np.arange(layout.n_channels)] /= 1.5
    r_eq = equivalent_resistance(layout, states, "dense")
    assert np.all(np.abs(delta - (r_eq[1:] - r_eq[0])) <= 1e-11 * r_eq[0])
    assert np.all(delta >= -1e-12 * r_eq[0])  # Rayleigh: +50 % on one channel never lowers an R_eq


def _with_widths(layout, widths_mm):
    """The layout with each channel's width replaced (so its own conductances spread as the widths do)."""
    import dataclasses

    channels = tuple(dataclasses.replace(c, width_mm=float(w)) for c, w in zip(layout.channels, widths_mm))
    return dataclasses.replace(layout, channels=channels)


@settings(max_examples=30, deadline=None)
@given(
    decades=st.floats(0.0, 12.0),
    factor=st.sampled_from([1.5, 1.0, 0.5, 20.0, 0.05]),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_undeformed_path_gives_the_public_paths_bits_on_every_route(decades, factor, seed):
    # the layout's own conductances (1 / R from its geometry), checked and routed once per layout object: the same
    # bits as channel_change_delta_ohm given them, whether they take the rank-one path (within 1e3) or the full solve

    rng = np.random.default_rng(seed)
    layout = _with_widths(grid_layout(3, 4), 10.0 ** rng.uniform(0.0, decades, grid_layout(3, 4).n_channels))
    own = channelchange.undeformed_channel_change_delta_ohm(layout, factor)
    g = 1.0 / layout.channel_resistance_ohm
    np.testing.assert_array_equal(own, channel_change_delta_ohm(layout, g, factor))
    np.testing.assert_array_equal(channelchange.undeformed_channel_change_delta_ohm(layout, factor), own)  # cached
    rank_one = g.max() <= GROUNDED_MAX_SPREAD * g.min()
    assert (channelchange._UNDEFORMED[id(layout)][1][1] is not None) == rank_one  # (weakref, (g, route))


def test_the_undeformed_path_on_a_stiff_layout_takes_the_exact_full_solve(paper_layout):

    widths = 10.0 ** np.random.default_rng(5).choice([-4.0, 2.0, 8.0], paper_layout.n_channels)  # 1e12 apart
    layout = _with_widths(paper_layout, widths)
    delta = channelchange.undeformed_channel_change_delta_ohm(layout, 1.5)
    assert channelchange._UNDEFORMED[id(layout)][1][1] is None  # beyond GROUNDED_MAX_SPREAD: the GTH full solve
    _assert_exact(layout, 1.0 / layout.channel_resistance_ohm, 1.5, delta, scale_rtol=1e-13)
    np.testing.assert_array_equal(paper_sensitivity(layout).delta_ohm, delta)
    for factor in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match="factor"):
            channelchange.undeformed_channel_change_delta_ohm(layout, factor)

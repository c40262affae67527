"""The fe-kernel channel integral's lookup (skin/kernelpinch.py, PinchKernel.depth_rows / offset_index /
lerp_rows): the per-state depth row and the per-spot offset index give the same A/A0 as the plain bilinear lookup at
every node, to 1e-12, on random presses with shut channels, presses beyond the kernel's reach, depth 0 and below,
deeper than the table, and a dry-run press's states sharing one (x, y)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.layout import load_layout
from neatskin.skin.fesetup import SHUT_AREA_RATIO
from neatskin.skin.kernel import PinchKernel, packaged_kernel_path, read_kernel
from neatskin.skin.kernelpinch import kernel_factor_and_share

LAYOUT = load_layout("protocols/skins/paper.toml")
KERNEL = read_kernel(packaged_kernel_path())


def reference_ratio(kernel: PinchKernel, offset_mm, depth_mm) -> np.ndarray:
    """The plain bilinear lookup, node by node (the implementation before the per-state rows)."""
    offset, depth = np.abs(np.asarray(offset_mm, float)), np.asarray(depth_mm, float)
    o, d = kernel.offsets_mm, kernel.depths_mm
    table = np.clip(kernel.area_ratio, 0.0, 1.0)
    for i in range(table.shape[0]):  # deeper than solved: the last solved value
        good = np.flatnonzero(np.isfinite(table[i]))
        table[i, good[-1] + 1 :] = table[i, good[-1]]
    fo = np.clip(offset / o[1], 0.0, o.size - 1.0)
    fd = np.clip(depth / d[1], 0.0, d.size - 1.0)
    io, jd = np.minimum(fo.astype(int), o.size - 2), np.minimum(fd.astype(int), d.size - 2)
    to, td = fo - io, fd - jd
    value = (table[io, jd] * (1 - to) + table[io + 1, jd] * to) * (1 - td) + (
        table[io, jd + 1] * (1 - to) + table[io + 1, jd + 1] * to
    ) * td
    value = np.where((offset > o[-1]) | (depth <= 0), 1.0, value)
    return np.where(value < SHUT_AREA_RATIO, 0.0, value)


def reference_factor_and_share(kernel, x, y, depth, nodes=48):
    """R / R0 and the displaced share, channel by channel and press by press, with the plain lookup."""
    xy = LAYOUT.xy_mm
    factor = np.ones((x.size, LAYOUT.n_channels))
    share = np.zeros_like(factor)
    frac = (np.arange(nodes) + 0.5) / nodes
    for c, (a, b) in enumerate(LAYOUT.channel_ends):
        vec = xy[b] - xy[a]
        length = np.hypot(*vec)
        points = xy[a] + frac[:, None] * vec  # the midpoint rule's nodes
        for p in range(x.size):
            r = np.hypot(points[:, 0] - x[p], points[:, 1] - y[p])
            if depth[p] <= 0 or r.min() >= kernel.offsets_mm[-1] or length == 0:
                continue
            ratio = reference_ratio(kernel, r, depth[p])
            with np.errstate(divide="ignore"):
                factor[p, c] = np.mean(1.0 / ratio)
            share[p, c] = np.mean(1.0 - ratio)
    return factor, share


def _assert_same(kernel, x, y, depth):
    got_f, got_s = kernel_factor_and_share(LAYOUT, kernel, x, y, depth)
    want_f, want_s = reference_factor_and_share(kernel, x, y, depth)
    assert np.array_equal(np.isinf(got_f), np.isinf(want_f))  # the same channels shut
    finite = np.isfinite(want_f)
    np.testing.assert_allclose(got_f[finite], want_f[finite], rtol=1e-12, atol=0)
    np.testing.assert_allclose(got_s, want_s, rtol=0, atol=1e-12)
    return want_f


def test_random_presses_match_the_plain_lookup_in_every_regime():
    rng = np.random.default_rng(7)
    n = 240
    x, y = rng.uniform(-14, 44, n), rng.uniform(-14, 44, n)  # the skin is 0..30 mm: some beyond reach
    depth = rng.uniform(-1.0, 6.0, n)  # depth <= 0 and deeper than the table's 4.5 mm
    depth[:20] = 0.0
    x[20:100], y[20:100] = np.repeat(x[20:30], 8), np.repeat(y[20:30], 8)  # a press's states share (x, y)
    x[100:108], y[100:108] = 100.0, -100.0  # far beyond reach
    factor = _assert_same(KERNEL, x, y, depth)
    # the sample covers what it claims (else the comparison proves little)
    assert np.isinf(factor).any()  # channels shut
    assert np.all(factor[:20] == 1.0) and np.all(factor[100:108] == 1.0)  # untouched: exactly the baseline
    assert (depth > KERNEL.depths_mm[-1]).sum() > 10 and ((factor > 1) & np.isfinite(factor)).any()


@settings(max_examples=25, deadline=None)
@given(
    x=st.floats(-12, 42),
    y=st.floats(-12, 42),
    depths=st.lists(st.floats(-0.5, 5.5), min_size=1, max_size=9),
)
def test_a_dry_run_press_its_states_sharing_one_spot_matches_the_plain_lookup(x, y, depths):
    depth = np.array(depths)
    _assert_same(KERNEL, np.full(depth.size, x), np.full(depth.size, y), depth)


def test_ratio_is_the_plain_bilinear_lookup_everywhere():
    rng = np.random.default_rng(3)
    offset = rng.uniform(-12, 12, (400, 5))
    offset[:, 0] = rng.choice(KERNEL.offsets_mm, 400)  # on the grid, the last offset included
    depth = rng.uniform(-1, 6, (400, 1))
    depth[:40] = rng.choice(KERNEL.depths_mm, (40, 1))
    got, want = KERNEL.ratio(offset, depth), reference_ratio(KERNEL, offset, depth)
    assert np.array_equal(got == 0, want == 0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert KERNEL.ratio(10.0 + 1e-9, 3.0) == 1.0 and KERNEL.ratio(3.0, 0.0) == 1.0


def test_the_comparison_can_fail_a_kernel_off_by_one_grid_step_is_caught():
    """Negative control: the same lookup on a kernel whose offsets are read one step off disagrees."""
    shifted = PinchKernel(
        KERNEL.offsets_mm, KERNEL.depths_mm, np.roll(KERNEL.area_ratio, 1, axis=0), KERNEL.force_n, "x", "{}"
    )
    x, y, depth = np.array([7.5, 15.0]), np.array([7.5, 3.0]), np.array([2.0, 3.5])
    got, _ = kernel_factor_and_share(LAYOUT, shifted, x, y, depth)
    want, _ = reference_factor_and_share(KERNEL, x, y, depth)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(got, want, rtol=1e-12)


def _means_of_lerp_rows(rows, lo, weight):
    """What the single-spot path computed before it used scratch memory: lerp_rows, then numpy's means."""
    ratio = PinchKernel.lerp_rows(rows, lo, weight)
    with np.errstate(divide="ignore"):
        return np.mean(1.0 / ratio, axis=-1), np.mean(ratio, axis=-1)


@settings(max_examples=30, deadline=None)
@given(
    depths=st.lists(st.floats(-0.5, 5.5), min_size=1, max_size=300),
    channels=st.integers(1, 7),
    nodes=st.integers(1, 60),
    seed=st.integers(0, 2**32 - 1),
)
def test_lerp_rows_means_are_the_means_of_lerp_rows_bit_for_bit(depths, channels, nodes, seed):
    """The dry run's records must not move by an ulp (the same bits as before the scratch memory): shut nodes,
    offsets beyond reach, depths at and below 0 and deeper than the table, any batch of states."""
    rng = np.random.default_rng(seed)
    rows = KERNEL.depth_rows(np.array(depths))
    lo, weight = KERNEL.offset_index(rng.uniform(-11.0, 11.0, (channels, nodes)))
    got, want = KERNEL.lerp_rows_means(rows, lo, weight), _means_of_lerp_rows(rows, lo, weight)
    for g, w in zip(got, want):
        assert g.shape == w.shape == (len(depths), channels)
        assert np.array_equal(g.view(np.int64), w.view(np.int64))


def test_lerp_rows_means_bit_test_can_fail_a_mean_that_adds_in_another_order():
    """Negative control: numpy's mean over a contiguous copy adds the nodes pairwise, not one after the other, and
    that moves some states by an ulp; the bit-for-bit comparison above sees it."""
    rng = np.random.default_rng(5)
    rows = KERNEL.depth_rows(rng.uniform(0.1, 4.0, 200))
    lo, weight = KERNEL.offset_index(rng.uniform(0.0, 9.0, (5, 48)))
    ratio = np.ascontiguousarray(PinchKernel.lerp_rows(rows, lo, weight))
    _, want = KERNEL.lerp_rows_means(rows, lo, weight)
    assert not np.array_equal(np.mean(ratio, axis=-1), want)
    np.testing.assert_allclose(np.mean(ratio, axis=-1), want, rtol=1e-15)  # only the rounding differs


def test_a_calls_results_survive_the_next_call_in_scratch_memory():
    """The single-spot path works in per-thread scratch memory (skin/scratch.py); what it returns is its own."""
    depth = np.linspace(0.2, 4.0, 150)
    first = kernel_factor_and_share(LAYOUT, KERNEL, np.full(150, 12.0), np.full(150, 9.0), depth)
    kept = [a.copy() for a in first]
    kernel_factor_and_share(LAYOUT, KERNEL, np.full(150, 3.0), np.full(150, 21.0), depth[::-1])
    for a, b in zip(first, kept):
        assert np.array_equal(a, b)
    assert (kept[0] > 1).any()

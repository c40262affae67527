"""The fast FSR press detection gives what the straightforward one (tests/fsr_reference.py) gave, value for value:
onsets, offsets, peaks and the baseline, on clean, noisy, drifting, chattering, edge-touching and broken traces."""

import itertools

import numpy as np
import pytest
from fsr_reference import detect_presses_reference
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from neatskin.acquisition import fsr, fsrkernels
from neatskin.acquisition.fsr import FsrModel, detect_presses


def force_trace(rate_hz, onsets_s, duration_s=8.5, peak_n=3.6, hold_s=1.2, ramp_s=0.6, noise_n=0.03, seed=0):
    """Trapezoid presses on a slow drift with white noise and single-sample spikes, in newtons."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    force = np.zeros_like(t)
    for t0 in onsets_s:
        up = np.clip((t - t0) / ramp_s, 0, 1)
        down = np.clip((t0 + 2 * ramp_s + hold_s - t) / ramp_s, 0, 1)
        force += peak_n * np.minimum(up, down)
    force += 0.2 * np.sin(2 * np.pi * t / (3 * duration_s)) + noise_n * rng.standard_normal(t.size)
    spikes = rng.choice(t.size, max(1, t.size // 400), replace=False)
    force[spikes] += rng.choice([-1, 1], spikes.size) * rng.uniform(2, 6, spikes.size)
    return force


def assert_same(signal, rate_hz, **kwargs):
    fast = detect_presses(signal, rate_hz, **kwargs)
    slow = detect_presses_reference(signal, rate_hz, **kwargs)
    np.testing.assert_array_equal(fast.onset, slow.onset)
    np.testing.assert_array_equal(fast.offset, slow.offset)
    np.testing.assert_array_equal(fast.peak_index, slow.peak_index)
    np.testing.assert_array_equal(fast.peak_force_n, slow.peak_force_n)  # exact, NaN where NaN
    np.testing.assert_array_equal(fast.baseline_n, slow.baseline_n)
    assert fast.onset.dtype == fast.offset.dtype == fast.peak_index.dtype == np.int64
    return fast


@pytest.mark.parametrize("rate_hz", [1000.0, 10_000.0, 1500.0, 600.0, 3000.0])  # blocks of 2, 20, 3, 1 and 6
@pytest.mark.parametrize(
    "onsets_s",
    [[2.2], [], [0.0], [6.5], [1.0, 4.5], [0.3, 1.6, 2.9, 4.2, 5.5]],
    ids=["one", "none", "at-start", "at-end", "two", "five"],
)
def test_same_presses_baseline_and_peaks(rate_hz, onsets_s):
    force = force_trace(rate_hz, onsets_s, hold_s=0.4 if len(onsets_s) > 2 else 1.2, ramp_s=0.2)
    det = assert_same(force, rate_hz)
    assert det.n_presses == len(onsets_s)  # the traces are what they claim to be


def test_same_on_the_dry_runs_fsr_volts():
    model = FsrModel()
    for seed in range(5):
        volts = model.volts(force_trace(1000.0, [2.2], seed=seed)) + 0.002 * np.random.default_rng(
            seed
        ).standard_normal(8500)
        det = assert_same(volts, 1000.0, expected=1, units="v", fsr=model)
        assert det.n_presses == 1


def test_same_when_the_force_chatters_around_the_thresholds():
    rate_hz = 1000.0
    rng = np.random.default_rng(4)
    t = np.arange(6000) / rate_hz
    plateau = np.where((t > 1.0) & (t < 4.0), 0.4 + 0.2 * rng.standard_normal(t.size), 0.0)
    assert_same(plateau, rate_hz)
    assert_same(plateau, rate_hz, min_press_s=0.0, min_gap_s=0.0, spike_samples=1)  # every crossing kept
    assert_same(np.full(3000, 1.0), rate_hz)  # always above on: one press from the first sample to the end


def test_same_on_short_broken_and_odd_input():
    rate_hz = 1000.0
    force = force_trace(rate_hz, [1.0], duration_s=3.0)
    assert_same(force[:5], rate_hz)  # fewer than 3 blocks: a constant baseline
    assert_same(force[:7], rate_hz)
    assert_same(force, rate_hz, spike_samples=5)  # another median window: scipy's filter
    assert_same(force, rate_hz, baseline_window_s=0.5)
    broken = force.copy()
    broken[1500] = np.nan
    assert_same(broken, rate_hz)  # a NaN sample: the fast paths step aside
    broken[1500] = np.inf
    assert_same(broken, rate_hz)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_presses=st.integers(0, 3),
    rate_hz=st.sampled_from([1000.0, 2000.0, 5000.0]),
    noise_n=st.floats(0.0, 0.3),
)
def test_property_same_as_reference(seed, n_presses, rate_hz, noise_n):
    rng = np.random.default_rng(seed)
    onsets = np.sort(rng.uniform(0.0, 7.0, n_presses)).tolist()
    assert_same(force_trace(rate_hz, onsets, hold_s=0.5, ramp_s=0.1, noise_n=noise_n, seed=seed), rate_hz)


def test_median_network_selects_the_middle_of_every_ordering():
    values = np.array([3.0, -1.0, 7.5, 0.0, 2.0, 9.0, -4.0])
    windows = np.array(list(itertools.permutations(values)))  # all 5,040 orders as consecutive windows
    trace = windows.ravel()
    np.testing.assert_array_equal(fsr._median_filter(trace, 7), ndimage.median_filter(trace, size=7, mode="nearest"))
    assert np.all(fsr._median_filter(trace, 7)[3::7] == 2.0)
    ties = np.random.default_rng(0).integers(0, 3, 5000).astype(float)
    np.testing.assert_array_equal(fsr._median_filter(ties, 7), ndimage.median_filter(ties, size=7, mode="nearest"))
    for n in range(7, 40):  # odd and even lengths: the last window pair is cut in half when n is odd
        for x in (trace[:n], trace[5 : 5 + n], ties[:n]):
            np.testing.assert_array_equal(fsr._median_filter(x, 7), ndimage.median_filter(x, size=7, mode="nearest"))


@pytest.mark.parametrize("block", [1, 2, 3, 6, 7, 8, 20])
def test_block_means_and_block_interpolation_match_numpy(block):
    rng = np.random.default_rng(block)
    x = rng.standard_normal(1000 * block + block // 2)
    m = x.size // block
    means = fsr._block_means(x, m, block)
    np.testing.assert_array_equal(means, x[: m * block].reshape(m, block).mean(axis=1))
    centres = (np.arange(m) + 0.5) * block
    np.testing.assert_array_equal(
        fsr._interp_blocks(means, x.size, block), np.interp(np.arange(x.size), centres, means)
    )
    free = rng.random(m) > 0.3
    free[100:300] = False
    free[:3] = False  # a gap at each end: the ends take the nearest free block's value
    free[-2:] = False
    edges = np.flatnonzero(np.diff(np.r_[1, free.astype(int), 1]))
    gaps = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
    assert fsr._union(gaps, m) == gaps
    np.testing.assert_array_equal(
        fsr._interp_free_blocks(means, gaps, x.size, block),
        np.interp(np.arange(x.size), centres[free], means[free]),
    )


def test_union_merges_overlapping_and_touching_runs_and_clips():
    assert fsr._union([(5, 8), (-3, 2), (7, 9), (9, 12), (20, 30), (14, 14)], 25) == [(0, 2), (5, 12), (20, 25)]
    assert fsr._union([], 10) == []


def test_newtons_in_place_is_the_divider_formula_and_leaves_the_trace_alone():
    model = FsrModel(vcc_v=3.3, rm_ohm=4_700.0)
    volts = np.random.default_rng(2).uniform(-0.5, 4.0, 1000)
    before = volts.copy()
    v = np.clip(volts, 0.0, 0.999 * 3.3)
    np.testing.assert_array_equal(model.newtons(volts), model.knee_n * v / (3.3 - v))
    np.testing.assert_array_equal(volts, before)
    assert model.newtons(1.65) == model.knee_n * 1.65 / (3.3 - 1.65)


@settings(max_examples=300, deadline=None)
@given(
    m=st.integers(3, 80),
    size=st.integers(3, 61).map(lambda k: k | 1),  # _baseline's windows: odd, at least 3
    level=st.sampled_from([0.0, 0.37, -1.25, 1e-3]),
    share=st.floats(0.05, 0.95),
    seed=st.integers(0, 2**32 - 1),
)
def test_a_flat_erosion_is_found_exactly_and_gives_the_filtered_baseline(m, size, level, share, seed):
    """_flat_erosion says "flat" exactly when the running minimum is one value, and then _baseline (which skips
    the filters) equals the opening, running mean and interpolation it replaces, value for value; the least
    value recurs with a random share, so flat and not flat both occur."""
    rng = np.random.default_rng(seed)
    blocks = np.where(rng.random(m) < share, level, level + rng.uniform(0.01, 2.0, m))
    eroded = ndimage.minimum_filter1d(blocks, size, mode="nearest")
    flat = fsr._flat_erosion(blocks, size)
    assert (flat is not None) == (eroded.min() == eroded.max())
    if flat is not None:
        assert flat == eroded[0]
    block, n = 2, 2 * m + 1
    rate_hz = 1000.0
    window_s = size * block / rate_hz
    opened = ndimage.maximum_filter1d(eroded, size, mode="nearest")
    smooth = ndimage.uniform_filter1d(opened, max(1, size // 4), mode="nearest")
    want = np.interp(np.arange(n), (np.arange(m) + 0.5) * block, smooth)
    np.testing.assert_array_equal(fsr._baseline(np.zeros(n), blocks, block, rate_hz, window_s), want)


@pytest.mark.parametrize("direct", [True, False], ids=["compiled", "public"])
def test_running_filters_are_scipys_bit_for_bit(monkeypatch, direct):
    """_running_mean / _running_extreme call scipy.ndimage's compiled routines directly; with them or through
    the public functions (a scipy without the private module) they give uniform_filter1d / minimum_filter1d /
    maximum_filter1d's bits, on strided views too."""
    if not direct:
        monkeypatch.setattr(fsrkernels, "_ndimage_kernels", lambda: None)
    rng = np.random.default_rng(5)
    for n, size in [(1, 1), (1, 533), (7, 3), (4270, 25), (8540, 5), (4270, 2135), (100, 101)]:
        x = rng.standard_normal(2 * n)[::2]  # a strided view
        np.testing.assert_array_equal(fsr._running_mean(x, size), ndimage.uniform_filter1d(x, size, mode="nearest"))
        np.testing.assert_array_equal(
            fsr._running_extreme(x, size, minimum=True), ndimage.minimum_filter1d(x, size, mode="nearest")
        )
        np.testing.assert_array_equal(
            fsr._running_extreme(x, size, minimum=False), ndimage.maximum_filter1d(x, size, mode="nearest")
        )


def test_private_filters_called_otherwise_are_refused_for_the_public_ones():
    """A later scipy may keep _nd_image's names and change their arguments or meaning: such kernels are refused
    (a TypeError, a missing name, or other bits than the public filters' on the probe trace), so the public
    filters are used; the scipy installed here passes."""
    from types import SimpleNamespace

    from scipy.ndimage import _nd_image

    assert fsrkernels._checked_kernels(_nd_image) is _nd_image
    real_mean, real_extreme = _nd_image.uniform_filter1d, _nd_image.min_or_max_filter1d
    changed = [
        SimpleNamespace(uniform_filter1d=lambda *a: real_mean(*a[:-1]), min_or_max_filter1d=real_extreme),  # arity
        SimpleNamespace(uniform_filter1d=lambda *a: real_mean(*a[:-1], 1), min_or_max_filter1d=real_extreme),  # origin
        SimpleNamespace(uniform_filter1d=real_mean, min_or_max_filter1d=lambda *a: real_extreme(*a[:-1], 1 - a[-1])),
        SimpleNamespace(uniform_filter1d=real_mean),  # a name gone
    ]
    for kernels in changed:
        assert fsrkernels._checked_kernels(kernels) is None


@settings(max_examples=300, deadline=None)
@given(
    n=st.integers(1, 400),
    levels=st.lists(st.sampled_from([0.0, 0.3, 0.6, 0.2, 0.5, 0.25]), min_size=1, max_size=40),
    seed=st.integers(0, 2**32 - 1),
)
def test_hysteresis_of_few_run_starts_is_the_array_version(n, levels, seed):
    """The Python walk over a few run starts gives the array version's onsets and offsets, on traces that sit
    on, between and across both thresholds (0.5 on, 0.25 off), ending high or low."""
    rng = np.random.default_rng(seed)
    x = np.asarray(levels)[rng.integers(0, len(levels), n)]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fsrkernels, "FEW_RUNS", 10**9)  # always the walk
        fast = fsr._hysteresis(x, 0.5, 0.25)
        patch.setattr(fsrkernels, "FEW_RUNS", -1)  # always the array version
        slow = fsr._hysteresis(x, 0.5, 0.25)
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_array_equal(fast[1], slow[1])
    assert fast[0].dtype == fast[1].dtype == np.int64

"""The FSR press detector's array kernels: the median of 7, scipy.ndimage's 1-D filters called directly, and the
hysteresis's intervals, each value for value the plain numpy / scipy call (tests/test_acq_fsr_exact.py).

They run once a press of a campaign, on its critical path, where a call's overhead counts as much as its
arithmetic; `neatskin.acquisition.fsr.detect_presses` composes them.
"""

from __future__ import annotations

import functools

import numpy as np


def _median_filter(force: np.ndarray, size: int) -> np.ndarray:
    """`ndimage.median_filter(force, size, mode="nearest")`, value for value; a window of 7 on a finite trace by
    whole-array min / max (a few microseconds each, where the rank filter's per-sample selection costs ~10 ns a
    sample), two outputs at a time.

    Windows k and k + 1 share six samples, split into two sorted runs of three, A (a1 <= a2 <= a3) and B; the
    six's 3rd and 4th smallest are s3 = min(a3, max(a2, b1), max(a1, b2), b3) and s4 = min(max(a3, b1),
    max(a2, b2), max(a1, b3)) (the k-th of a union of sorted runs is the least max(a_i, b_j) over i + j = k), and
    each window's median is its own seventh sample clamped to [s3, s4]: about 14 array passes for 22 of a
    median-of-7 network. Even and odd samples are split first so that every pass reads contiguous memory."""
    n = force.shape[0]
    if size != 7 or n < 7 or not np.isfinite(force).all():
        from scipy import ndimage

        return ndimage.median_filter(force, size=size, mode="nearest")
    pairs = (n + 1) // 2
    padded = np.empty(2 * pairs + 6)  # 3 copies of each end ("nearest"), one more at the end when n is odd
    padded[:3], padded[3 : n + 3], padded[n + 3 :] = force[0], force, force[-1]
    even, odd = padded[0::2].copy(), padded[1::2].copy()
    # windows 2k and 2k + 1 share samples 2k + 1 .. 2k + 6 of the padded trace: A = 2k + 1 .. 2k + 3, B = the rest
    a1, a2, a3 = _sorted3(odd[:pairs], even[1 : pairs + 1], odd[1 : pairs + 1])
    b1, b2, b3 = _sorted3(even[2 : pairs + 2], odd[2 : pairs + 2], even[3 : pairs + 3])
    s3 = np.maximum(a2, b1)
    np.minimum(s3, np.maximum(a1, b2), out=s3)
    np.minimum(s3, a3, out=s3)
    np.minimum(s3, b3, out=s3)
    s4 = np.maximum(a3, b1)
    np.minimum(s4, np.maximum(a2, b2), out=s4)
    np.minimum(s4, np.maximum(a1, b3), out=s4)
    out = np.empty(2 * pairs)
    own = np.minimum(even[:pairs], s4)  # window 2k's own sample: padded 2k; window 2k + 1's: padded 2k + 7
    np.maximum(own, s3, out=out[0::2])
    np.minimum(odd[3 : pairs + 3], s4, out=own)
    np.maximum(own, s3, out=out[1::2])
    return out[:n]


def _sorted3(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Elementwise the smallest, middle and largest of three arrays (three compare-exchanges)."""
    low, high = np.minimum(x, y), np.maximum(x, y)
    top = np.maximum(high, z)
    np.minimum(high, z, out=high)
    bottom = np.minimum(low, high)
    np.maximum(low, high, out=low)
    return bottom, low, top


@functools.cache
def _ndimage_kernels():
    """scipy.ndimage's compiled 1-D filters (a private module), or None where this scipy lacks them or calls them
    otherwise (`_checked_kernels`, once a process)."""
    try:
        from scipy.ndimage import _nd_image
    except ImportError:
        return None
    return _checked_kernels(_nd_image)


def _checked_kernels(kernels):
    """kernels if its uniform_filter1d and min_or_max_filter1d, called as _running_mean and _running_extreme call
    them, give the public filters' bits on a probe trace; else None. A private signature may change with no name
    gone: an error or other bits then mean the public filters are used."""
    from scipy import ndimage

    probe = np.sin(np.arange(40.0) * 0.7) + np.arange(40.0) * 0.05
    try:
        for size in (1, 4, 7):
            mean, low, high = np.empty(40), np.empty(40), np.empty(40)
            kernels.uniform_filter1d(probe, size, 0, mean, 0, 0.0, 0)
            kernels.min_or_max_filter1d(probe, size, 0, low, 0, 0.0, 0, 1)
            kernels.min_or_max_filter1d(probe, size, 0, high, 0, 0.0, 0, 0)
            if not (
                np.array_equal(mean, ndimage.uniform_filter1d(probe, size, mode="nearest"))
                and np.array_equal(low, ndimage.minimum_filter1d(probe, size, mode="nearest"))
                and np.array_equal(high, ndimage.maximum_filter1d(probe, size, mode="nearest"))
            ):
                return None
    except Exception:  # noqa: BLE001 - AttributeError, TypeError, ValueError: another scipy's private module
        return None
    return kernels


def _running_mean(x: np.ndarray, size: int) -> np.ndarray:
    """`ndimage.uniform_filter1d(x, size, mode="nearest")`: for a 1-D float array, the compiled routine that call
    ends in, called directly (the same routine and arguments, so the same bits; its wrapper and scipy's array
    API dispatch cost more than the filter itself on a press's trace, once a press on the critical path)."""
    kernels = _ndimage_kernels()
    if kernels is None or x.ndim != 1 or x.dtype != np.float64:
        from scipy import ndimage

        return ndimage.uniform_filter1d(x, size, mode="nearest")
    out = np.empty(x.shape)
    kernels.uniform_filter1d(x, size, 0, out, 0, 0.0, 0)  # axis 0, mode "nearest" (code 0), cval 0, origin 0
    return out


def _running_extreme(x: np.ndarray, size: int, *, minimum: bool) -> np.ndarray:
    """`ndimage.minimum_filter1d` (or `maximum_filter1d`) of x with `size` and mode "nearest", as _running_mean."""
    kernels = _ndimage_kernels()
    if kernels is None or x.ndim != 1 or x.dtype != np.float64:
        from scipy import ndimage

        extreme = ndimage.minimum_filter1d if minimum else ndimage.maximum_filter1d
        return extreme(x, size, mode="nearest")
    out = np.empty(x.shape)
    kernels.min_or_max_filter1d(x, size, 0, out, 0, 0.0, 0, int(minimum))
    return out


def _hysteresis(x: np.ndarray, on: float, off: float) -> tuple[np.ndarray, np.ndarray]:
    """Intervals [onset, offset) where x went above `on` and has not yet fallen below `off`.

    The state changes only where a run of samples above `on` (or below `off`) begins: a high run start is an
    onset when it is the first, or a low run started since the previous high one; a low run start is an
    offset when a high run started since the previous low one (or before the first)."""
    n = x.shape[0]
    high = np.zeros(n + 1, dtype=bool)
    low = np.zeros(n + 1, dtype=bool)
    np.greater_equal(x, on, out=high[1:])
    np.less(x, off, out=low[1:])
    high_at = (high[1:] > high[:-1]).nonzero()[0]  # sample indices where a high run begins
    low_at = (low[1:] > low[:-1]).nonzero()[0]
    if high_at.size + low_at.size <= FEW_RUNS:
        return _hysteresis_of_few(high_at.tolist(), low_at.tolist(), n)
    lows_before = low_at.searchsorted(high_at)
    highs_before = high_at.searchsorted(low_at)
    onset = high_at[np.concatenate(([True], lows_before[1:] > lows_before[:-1]))[: high_at.size]]
    offset = low_at[np.concatenate((highs_before[:1] > 0, highs_before[1:] > highs_before[:-1]))]
    if high_at.size and (low_at.size == 0 or high_at[-1] > low_at[-1]):
        offset = np.concatenate([offset, [n]])
    return onset.astype(np.int64), offset.astype(np.int64)


FEW_RUNS = 64  # up to this many run starts (a clean press has 3 to 5) the state machine runs in Python


def _hysteresis_of_few(high_at: list[int], low_at: list[int], n: int) -> tuple[np.ndarray, np.ndarray]:
    """`_hysteresis`'s intervals from its run starts, by walking them in order: a high run starting while off is
    an onset, a low run starting while on an offset (a dozen small array calls cost more for a few starts)."""
    onsets: list[int] = []
    offsets: list[int] = []
    pressed = False
    i = j = 0
    while i < len(high_at) or j < len(low_at):
        if j == len(low_at) or (i < len(high_at) and high_at[i] < low_at[j]):
            if not pressed:
                onsets.append(high_at[i])
                pressed = True
            i += 1
        else:
            if pressed:
                offsets.append(low_at[j])
                pressed = False
            j += 1
    if pressed:
        offsets.append(n)
    return np.array(onsets, dtype=np.int64), np.array(offsets, dtype=np.int64)

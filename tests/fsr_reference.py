"""The FSR press detection as it was before it was made fast (commit 80806b2), kept as the oracle that
tests/test_acq_fsr_exact.py holds the fast one to, value for value. Not used by the package."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from neatskin.acquisition.fsr import FsrModel, PressDetection


def detect_presses_reference(
    signal: np.ndarray,
    rate_hz: float,
    expected: int = 1,
    *,
    units: str = "n",
    fsr: FsrModel | None = None,
    on_threshold_n: float = 0.5,
    off_threshold_n: float = 0.25,
    min_press_s: float = 0.05,
    min_gap_s: float = 0.05,
    spike_samples: int = 7,
    baseline_window_s: float | None = None,
) -> PressDetection:
    """Find the presses on a force trace (newtons, or FSR volts with units="v").

    baseline_window_s must exceed the longest press (default: the whole trace's length / 2,
    at least 2 s); the baseline under a press is the running minimum around it.
    """
    x = np.asarray(signal, dtype=float)
    force = (fsr or FsrModel()).newtons(x) if units == "v" else x
    n = force.shape[0]
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return PressDetection(empty, empty, empty, np.zeros(0), expected, rate_hz, np.zeros(0))
    k = max(1, int(spike_samples)) | 1
    clean = ndimage.median_filter(force, size=k, mode="nearest")
    min_len, min_gap = int(round(min_press_s * rate_hz)), int(round(min_gap_s * rate_hz))
    # pass 1: a running-minimum baseline (below the truth where the drift is convex) finds the presses;
    # pass 2: the baseline is the smoothed trace outside them, bridged linearly across each press
    rough = _baseline(clean, rate_hz, baseline_window_s)
    onset, offset = _debounce(*_hysteresis(clean - rough, on_threshold_n, off_threshold_n), min_len, min_gap)
    baseline = _bridged_baseline(clean, rate_hz, onset, offset)
    above = clean - baseline
    onset, offset = _debounce(*_hysteresis(above, on_threshold_n, off_threshold_n), min_len, min_gap)
    # peak on a 5 ms average, so white noise does not bias it up; one argmax per press, not per sample
    smooth = ndimage.uniform_filter1d(above, max(1, int(round(0.005 * rate_hz))), mode="nearest")
    peak_index = np.array([a + int(np.argmax(smooth[a:b])) for a, b in zip(onset, offset)], dtype=np.int64)
    peak = smooth[peak_index] if peak_index.size else np.zeros(0)
    return PressDetection(onset, offset, peak_index.astype(np.int64), peak, expected, rate_hz, baseline)


def _baseline(force: np.ndarray, rate_hz: float, window_s: float | None) -> np.ndarray:
    n = force.shape[0]
    window_s = window_s if window_s is not None else max(2.0, n / rate_hz / 2)
    # work on block medians (~2 ms) so a long window stays cheap
    block = max(1, int(rate_hz // 500))
    m = n // block
    if m < 3:
        return np.full(n, float(np.median(force)))
    blocks = force[: m * block].reshape(m, block).mean(axis=1)  # spikes are already median-filtered out
    size = max(3, int(round(window_s * rate_hz / block)) | 1)
    opened = ndimage.maximum_filter1d(ndimage.minimum_filter1d(blocks, size, mode="nearest"), size, mode="nearest")
    # smooth the staircase of the opening, then back to the sample grid
    smooth = ndimage.uniform_filter1d(opened, max(1, size // 4), mode="nearest")
    centres = (np.arange(m) + 0.5) * block
    return np.interp(np.arange(n), centres, smooth)


def _bridged_baseline(force: np.ndarray, rate_hz: float, onset: np.ndarray, offset: np.ndarray) -> np.ndarray:
    n = force.shape[0]
    block = max(1, int(rate_hz // 500))
    m = n // block
    if m < 3:
        return np.full(n, float(np.median(force)))
    blocks = force[: m * block].reshape(m, block).mean(axis=1)  # spikes are already median-filtered out
    smooth = ndimage.uniform_filter1d(blocks, max(1, int(round(0.05 * rate_hz / block))), mode="nearest")
    margin = int(round(0.1 * rate_hz))  # keep 100 ms around each press out of the baseline
    inside = np.zeros(n + 1, dtype=np.int64)
    np.add.at(inside, np.maximum(onset - margin, 0), 1)
    np.add.at(inside, np.minimum(offset + margin, n), -1)
    pressed = np.cumsum(inside[:n]) > 0
    centres = (np.arange(m) + 0.5) * block
    free = ~pressed[(centres).astype(np.int64)]
    if free.sum() < 2:
        return np.full(n, float(np.median(force)))
    # the smoothing window must not reach into a press: use only blocks whose 50 ms window is free
    free &= (
        ndimage.minimum_filter1d(free.astype(np.int8), max(1, int(round(0.05 * rate_hz / block))), mode="nearest") > 0
    )
    if free.sum() < 2:
        return np.full(n, float(np.median(force)))
    return np.interp(np.arange(n), centres[free], smooth[free])


def _hysteresis(x: np.ndarray, on: float, off: float) -> tuple[np.ndarray, np.ndarray]:
    """Intervals [onset, offset) where x went above `on` and has not yet fallen below `off`."""
    event = np.zeros(x.shape[0], dtype=np.int8)
    event[x >= on] = 1
    event[x < off] = -1
    idx = np.where(event != 0, np.arange(x.shape[0]), -1)
    last = np.maximum.accumulate(idx)
    state = np.where(last >= 0, event[np.maximum(last, 0)] == 1, False)
    edges = np.diff(np.concatenate([[False], state, [False]]).astype(np.int8))
    return np.flatnonzero(edges == 1).astype(np.int64), np.flatnonzero(edges == -1).astype(np.int64)


def _debounce(onset: np.ndarray, offset: np.ndarray, min_len: int, min_gap: int) -> tuple[np.ndarray, np.ndarray]:
    if onset.size == 0:
        return onset, offset
    gap = onset[1:] - offset[:-1]
    keep_start = np.concatenate([[True], gap >= min_gap])  # a short gap merges with the previous press
    group = np.cumsum(keep_start) - 1
    onset2 = onset[keep_start]
    offset2 = np.zeros(onset2.size, dtype=np.int64)
    np.maximum.at(offset2, group, offset)
    long_enough = offset2 - onset2 >= min_len
    return onset2[long_enough], offset2[long_enough]

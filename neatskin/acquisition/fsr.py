"""The force-sensing resistor: its divider model (newtons <-> volts) and press detection on the force channel.

FSR400 in a voltage divider: R_fsr = k / F, V = Vcc * Rm / (Rm + R_fsr) = Vcc * F / (F + k / Rm),
so F = (k / Rm) * V / (Vcc - V). With no force R_fsr is open and V = 0.

Press detection (pure, vectorised): a median filter removes isolated spikes, a morphological
opening (running minimum then maximum over a window longer than a press) tracks the slow
baseline drift, and a hysteresis threshold on the force above the baseline (on above
on_threshold_n, off below off_threshold_n) with debounce (presses shorter than min_press_s
dropped, gaps shorter than min_gap_s merged) gives onset, offset and peak per press.

It runs once per press of a campaign, so each step is a handful of whole-array operations: the median of 7
two windows at a time, the opening skipped when the erosion is flat, block means and interpolation on the
block grid without a search, hysteresis from the run starts alone (the array kernels are in
neatskin.acquisition.fsrkernels). Each fast step equals the plain numpy / scipy call value for value (the plain
version is kept as the oracle in tests/fsr_reference.py) and hands non-finite input to that call.
scipy.ndimage (a few hundred ms to import) is imported on first use; its compiled 1-D filters are called
directly (the same routine, the same bits).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from neatskin.acquisition.fsrkernels import _hysteresis, _median_filter, _running_extreme, _running_mean
from neatskin.errors import ConfigError


@dataclass(frozen=True)
class FsrModel:
    vcc_v: float = 5.0
    rm_ohm: float = 10_000.0  # divider resistor
    k_ohm_n: float = 10_000.0  # R_fsr * F: ~10 kohm at 1 N for the FSR400

    def __post_init__(self) -> None:
        for name in ("vcc_v", "rm_ohm", "k_ohm_n"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(
                    f"{name} must be > 0, got {value!r}", file="<fsr model>", field=name, fix=f"set {name} > 0"
                )

    @property
    def knee_n(self) -> float:
        """The force at which V = Vcc / 2."""
        return self.k_ohm_n / self.rm_ohm

    def volts(self, force_n: np.ndarray) -> np.ndarray:
        force = np.maximum(np.asarray(force_n, dtype=float), 0.0)
        return self.vcc_v * force / (force + self.knee_n)

    def newtons(self, fsr_v: np.ndarray) -> np.ndarray:
        """Invert the divider; volts at or above Vcc map to the force at 99.9 % of Vcc, below 0 to 0 N."""
        v = np.clip(np.asarray(fsr_v, dtype=float), 0.0, 0.999 * self.vcc_v)
        if not isinstance(v, np.ndarray) or v.ndim == 0:
            return self.knee_n * v / (self.vcc_v - v)
        below = np.subtract(self.vcc_v, v)
        np.multiply(v, self.knee_n, out=v)  # knee_n * v / (vcc_v - v), in place: once a press, on every sample
        return np.divide(v, below, out=v)


@dataclass(frozen=True, eq=False)
class PressDetection:
    """Presses found on one force trace, in sample indices of that trace ([onset, offset))."""

    onset: np.ndarray  # (presses,) int
    offset: np.ndarray  # (presses,) int, exclusive
    peak_index: np.ndarray  # (presses,) int
    peak_force_n: np.ndarray  # (presses,) above the baseline
    expected: int
    rate_hz: float
    baseline_n: np.ndarray = field(repr=False)  # (samples,)

    @property
    def n_presses(self) -> int:
        return int(self.onset.shape[0])

    @property
    def flags(self) -> tuple[str, ...]:
        if self.n_presses == 0 and self.expected > 0:
            return ("missed",)
        if self.n_presses > self.expected:
            return ("multiple",)
        if self.n_presses < self.expected:
            return ("missed",)
        return ()

    @property
    def ok(self) -> bool:
        return not self.flags

    @property
    def duration_s(self) -> np.ndarray:
        return (self.offset - self.onset) / self.rate_hz


def detect_presses(
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
    if units not in ("n", "v"):
        raise ConfigError(f"units must be 'n' or 'v', got {units!r}", field="units", fix="use 'n' or 'v'")
    if not 0 < off_threshold_n < on_threshold_n:
        raise ConfigError(
            "thresholds need 0 < off_threshold_n < on_threshold_n",
            field="off_threshold_n",
            fix="set off below on for hysteresis",
        )
    x = np.asarray(signal, dtype=float)
    force = (fsr or FsrModel()).newtons(x) if units == "v" else x
    n = force.shape[0]
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return PressDetection(empty, empty, empty, np.zeros(0), expected, rate_hz, np.zeros(0))
    clean = _median_filter(force, max(1, int(spike_samples)) | 1)
    min_len, min_gap = int(round(min_press_s * rate_hz)), int(round(min_gap_s * rate_hz))
    # both baselines work on block means (~2 ms): spikes are already median-filtered out
    block = max(1, int(rate_hz // 500))
    m = n // block
    blocks = _block_means(clean, m, block) if m >= 3 else None
    # pass 1: a running-minimum baseline (below the truth where the drift is convex) finds the presses;
    # pass 2: the baseline is the smoothed trace outside them, bridged linearly across each press
    rough = _baseline(clean, blocks, block, rate_hz, baseline_window_s)
    onset, offset = _debounce(*_hysteresis(clean - rough, on_threshold_n, off_threshold_n), min_len, min_gap)
    baseline = _bridged_baseline(clean, blocks, block, rate_hz, onset, offset)
    above = clean - baseline
    onset, offset = _debounce(*_hysteresis(above, on_threshold_n, off_threshold_n), min_len, min_gap)
    # peak on a 5 ms average, so white noise does not bias it up; one argmax per press, not per sample
    smooth = _running_mean(above, max(1, int(round(0.005 * rate_hz))))
    peak_index = np.array([a + int(np.argmax(smooth[a:b])) for a, b in zip(onset, offset)], dtype=np.int64)
    peak = smooth[peak_index] if peak_index.size else np.zeros(0)
    return PressDetection(onset, offset, peak_index, peak, expected, rate_hz, baseline)


def _baseline(
    force: np.ndarray, blocks: np.ndarray | None, block: int, rate_hz: float, window_s: float | None
) -> np.ndarray:
    n = force.shape[0]
    window_s = window_s if window_s is not None else max(2.0, n / rate_hz / 2)
    if blocks is None:
        return np.full(n, float(np.median(force)))
    size = max(3, int(round(window_s * rate_hz / block)) | 1)
    level = _flat_erosion(blocks, size)
    if level is not None:
        # the opening is flat, and a running mean of a constant is one value, its first (0 stays 0; otherwise the
        # uniform filter of one sample gives the sum of `size // 4` copies in the filter's own order)
        smooth = level if level == 0 else _running_mean(np.full(1, level), max(1, size // 4))[0]
        return np.full(n, smooth)
    opened = _running_extreme(_running_extreme(blocks, size, minimum=True), size, minimum=False)
    # smooth the staircase of the opening, then back to the sample grid
    smooth = _running_mean(opened, max(1, size // 4))
    return _interp_blocks(smooth, n, block)


def _flat_erosion(blocks: np.ndarray, size: int) -> float | None:
    """The value of `ndimage.minimum_filter1d(blocks, size, mode="nearest")` when it is one value everywhere, else
    None: when every window (`size` odd: [k - size // 2, k + size // 2], cut at the ends) holds a block equal to the
    least one. That is the usual trace: the divider reads 0 V, hence 0 N, wherever nothing presses, so the least
    block recurs all along, and the erosion, the opening and its running mean are that value (a zero's sign aside,
    which no comparison sees)."""
    least = float(blocks.min())
    if not math.isfinite(least):
        return None
    at = (blocks == least).nonzero()[0]
    half, last = size // 2, blocks.shape[0] - 1
    if at[0] > half or at[-1] < last - half or (at.size > 1 and int((at[1:] - at[:-1]).max()) > size):
        return None
    return least


def _bridged_baseline(
    force: np.ndarray, blocks: np.ndarray | None, block: int, rate_hz: float, onset: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    n = force.shape[0]
    if blocks is None:
        return np.full(n, float(np.median(force)))
    m = blocks.shape[0]
    window = max(1, int(round(0.05 * rate_hz / block)))
    smooth = _running_mean(blocks, window)
    margin = int(round(0.1 * rate_hz))  # keep 100 ms around each press out of the baseline
    # a block is pressed when its centre sample lies within a press widened by the margin
    centre_sample = _block_centre_samples(m, block)
    first = centre_sample.searchsorted(np.maximum(onset - margin, 0)).tolist()
    stop = centre_sample.searchsorted(np.minimum(offset + margin, n)).tolist()
    if m - sum(b - a for a, b in _union(zip(first, stop), m)) < 2:
        return np.full(n, float(np.median(force)))
    # the smoothing window must not reach into a press: use only blocks whose 50 ms window is free, i.e. what
    # `ndimage.minimum_filter1d(free, window, mode="nearest")` leaves, its window being [k - window // 2, k + reach]
    reach = window - window // 2 - 1
    gaps = _union(((a - reach, b + window // 2) for a, b in zip(first, stop) if a < b), m)
    if m - sum(b - a for a, b in gaps) < 2:
        return np.full(n, float(np.median(force)))
    return _interp_free_blocks(smooth, gaps, n, block)


def _union(intervals, m: int) -> list[tuple[int, int]]:
    """The [start, stop) block runs that the intervals cover, clipped to [0, m), sorted, disjoint and not touching."""
    runs: list[tuple[int, int]] = []
    for a, b in sorted(intervals):
        a, b = max(a, 0), min(b, m)
        if a >= b:
            continue
        if runs and a <= runs[-1][1]:
            runs[-1] = (runs[-1][0], max(runs[-1][1], b))
        else:
            runs.append((a, b))
    return runs


@functools.lru_cache(maxsize=8)
def _block_centre_samples(m: int, block: int) -> np.ndarray:
    """The sample index each block is judged by: int((k + 0.5) * block), read only."""
    centres = ((np.arange(m) + 0.5) * block).astype(np.int64)
    centres.flags.writeable = False
    return centres


def _interp_blocks(values: np.ndarray, n: int, block: int) -> np.ndarray:
    """`np.interp(np.arange(n), (np.arange(m) + 0.5) * block, values)`, value for value, without the search:
    sample k * block + r lies at a fixed offset from a block centre, so each offset r is one column."""
    m = values.shape[0]
    if not np.isfinite(values).all():
        return np.interp(np.arange(n), (np.arange(m) + 0.5) * block, values)
    half = 0.5 * block
    slope = (values[1:] - values[:-1]) / float(block)  # np.interp's (dy[j+1] - dy[j]) / (dx[j+1] - dx[j])
    out = np.empty(n)
    grid = out[: m * block].reshape(m, block)
    head = values[:-1]
    for r in range(block):
        if r < half:  # between the previous block's centre and this one's; left of the first centre
            np.add(slope if r + half == 1.0 else slope * (r + half), head, out=grid[1:, r])  # x * 1.0 == x
            grid[0, r] = values[0]
        elif r > half:  # between this block's centre and the next one's; right of the last centre
            np.add(slope * (r - half), head, out=grid[:-1, r])
            grid[-1, r] = values[-1]
        else:  # on a centre
            grid[:, r] = values
    out[m * block :] = values[-1]
    return out
    out[m * block :] = values[-1]
    return out


def _interp_free_blocks(values: np.ndarray, gaps: list[tuple[int, int]], n: int, block: int) -> np.ndarray:
    """`np.interp(np.arange(n), centres[free], values[free])`, value for value, where the blocks that are not free
    are the runs `gaps` (from `_union`): the interpolation over all blocks, then each gap bridged from the free
    block before it to the one after it."""
    m = values.shape[0]
    if not np.isfinite(values).all():
        free = np.ones(m, dtype=bool)
        for a, b in gaps:
            free[a:b] = False
        return np.interp(np.arange(n), ((np.arange(m) + 0.5) * block)[free], values[free])
    out = _interp_blocks(values, n, block)
    half = 0.5 * block
    first = gaps[0][1] if gaps and gaps[0][0] == 0 else 0
    last = gaps[-1][0] - 1 if gaps and gaps[-1][1] == m else m - 1
    # samples left of the first free centre take its value, right of the last free centre the last one's
    out[: math.ceil(first * block + half)] = values[first]
    out[math.ceil(last * block + half) :] = values[last]
    for a, b in gaps:
        if a == 0 or b == m:
            continue
        a -= 1  # bridged from the free block before the gap to the free block after it (b)
        ca, cb = a * block + half, b * block + half
        slope = (values[b] - values[a]) / (cb - ca)
        lo, hi = math.floor(ca) + 1, math.ceil(cb)  # the samples strictly between the two centres
        np.add(slope * np.arange(lo - ca, hi - ca), values[a], out=out[lo:hi])
    return out


def _block_means(force: np.ndarray, m: int, block: int) -> np.ndarray:
    """`force[: m * block].reshape(m, block).mean(axis=1)`, value for value: numpy sums fewer than 8 values
    in order, so short blocks are summed column by column (a reduction over a short axis is slow)."""
    grid = force[: m * block].reshape(m, block)
    if block >= 8:
        return grid.mean(axis=1)
    total = grid[:, 0].copy()
    for r in range(1, block):
        total += grid[:, r]
    return total / float(block)


def _debounce(onset: np.ndarray, offset: np.ndarray, min_len: int, min_gap: int) -> tuple[np.ndarray, np.ndarray]:
    if onset.size <= 1:
        long_enough = offset - onset >= min_len
        return onset[long_enough], offset[long_enough]
    gap = onset[1:] - offset[:-1]
    keep_start = np.concatenate([[True], gap >= min_gap])  # a short gap merges with the previous press
    group = np.cumsum(keep_start) - 1
    onset2 = onset[keep_start]
    offset2 = np.zeros(onset2.size, dtype=np.int64)
    np.maximum.at(offset2, group, offset)
    long_enough = offset2 - onset2 >= min_len
    return onset2[long_enough], offset2[long_enough]

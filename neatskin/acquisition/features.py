"""Per-press features: for every pair, R while pressed, the unpressed baseline around the press, dR, and the sample ranges they came from.

A pair's estimate from one sweep counts as "pressed" when its live window lies wholly inside
[onset + margin, offset - margin), and as "baseline" when it lies wholly before
onset - margin (or, if there is none before, wholly after offset + margin). Each group is
averaged over its sweeps. Windows and onsets are in the acquisition's global sample index.

Open circuits stay +inf (never NaN): dR = +inf when only the pressed value is open,
-inf when only the baseline is, and 0 with OPEN_CIRCUIT set when both are. A clipped estimate
(CLIPPED: the AI's range or the mux rails; V / I is then not the skin's R) is no value either and
follows the same rules, as the campaign's row does (acquisition.pressvalues): a group with a
clipped sweep is +inf, never the estimate's finite, low reading. Wherever a group is open or
clipped the uncertainty of dR is +inf. A pair with no pressed (or no baseline) window gets
R = 0, dR = 0, uncertainty +inf and NO_PRESSED (or NO_BASELINE): check the flags, not the values.

`features_from_acquisition` is the whole per-press pipeline: demodulate every sweep, find the
press on the FSR channel, and take the features around it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from neatskin.acquisition.daq.base import Acquisition
from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.estimates import PairEstimates, PairFlag
from neatskin.acquisition.fsr import FsrModel, PressDetection, detect_presses
from neatskin.acquisition.sequence import Sweep


@dataclass(frozen=True, eq=False)
class PressFeatures:
    delta_r_ohm: np.ndarray  # (pairs,) pressed minus baseline
    resistance_ohm: np.ndarray  # (pairs,) pressed
    baseline_ohm: np.ndarray  # (pairs,)
    uncertainty_ohm: np.ndarray  # (pairs,) of delta_r_ohm
    flags: np.ndarray  # (pairs,) uint8 PairFlag: OR of the estimates used, NO_PRESSED / NO_BASELINE
    pressed_samples: np.ndarray = field(repr=False)  # (pairs, 2) [first start, last stop) of the windows used
    baseline_samples: np.ndarray = field(repr=False)  # (pairs, 2); (-1, -1) when none
    n_pressed: np.ndarray = field(repr=False)  # (pairs,) sweeps averaged
    n_baseline: np.ndarray = field(repr=False)


def _group(est: PairEstimates, use: np.ndarray):
    n = use.sum(axis=0)
    # an open or clipped sweep is no value (the campaign row's rule): the group is +inf, its uncertainty too
    clipped = (est.flags & np.uint8(PairFlag.CLIPPED)) != 0
    valid = np.isfinite(est.resistance_ohm) & ~clipped
    no_value = (use & ~valid).any(axis=0)
    mean = np.where(no_value, np.inf, np.where(use & valid, est.resistance_ohm, 0.0).sum(axis=0) / np.maximum(n, 1))
    u2 = np.where(use & valid, est.uncertainty_ohm, 0.0) ** 2
    u = np.where(no_value, np.inf, np.sqrt(u2.sum(axis=0)) / np.maximum(n, 1))
    flags = np.bitwise_or.reduce(np.where(use, est.flags, 0).astype(np.uint8), axis=0)
    starts = np.where(use, est.windows[..., 0], np.iinfo(np.int64).max).min(axis=0)
    stops = np.where(use, est.windows[..., 1], -1).max(axis=0)
    span = np.stack([np.where(n > 0, starts, -1), np.where(n > 0, stops, -1)], axis=1)
    return mean, u, flags, span, n


def press_features(
    estimates: PairEstimates, onset_sample: int, offset_sample: int, margin_samples: int = 0
) -> PressFeatures:
    """dR per pair for one press [onset_sample, offset_sample) from estimates of the sweeps around it."""
    start, stop = estimates.windows[..., 0], estimates.windows[..., 1]
    pressed = (start >= onset_sample + margin_samples) & (stop <= offset_sample - margin_samples)
    before = stop <= onset_sample - margin_samples
    after = start >= offset_sample + margin_samples
    baseline = np.where(before.any(axis=0), before, after)
    r_p, u_p, f_p, span_p, n_p = _group(estimates, pressed)
    r_b, u_b, f_b, span_b, n_b = _group(estimates, baseline)
    flags = f_p | f_b
    flags[n_p == 0] |= np.uint8(PairFlag.NO_PRESSED)
    flags[n_b == 0] |= np.uint8(PairFlag.NO_BASELINE)
    both_open = np.isinf(r_p) & np.isinf(r_b)
    with np.errstate(invalid="ignore"):
        delta = np.where(both_open, 0.0, r_p - r_b)
    missing = (n_p == 0) | (n_b == 0)
    delta = np.where(missing, 0.0, delta)
    r_p = np.where(n_p == 0, 0.0, r_p)
    r_b = np.where(n_b == 0, 0.0, r_b)
    u = np.where(missing, np.inf, np.sqrt(u_p**2 + u_b**2))
    return PressFeatures(delta, r_p, r_b, u, flags, span_p, span_b, n_p, n_b)


def features_from_acquisition(
    acq: Acquisition,
    sweep: Sweep,
    method: str = "lockin",
    window: int = 10,
    expected: int = 1,
    fsr: FsrModel = FsrModel(),
    margin_s: float = 0.0,
    **detect_kwargs,
) -> tuple[PressFeatures, PressDetection, PairEstimates]:
    """Demodulate, detect the press on the FSR channel, and return its features with what they came from.

    With several presses detected the one with the highest peak is used (the detection's flags
    say "multiple"); with none, every pair is NO_PRESSED (flag "missed").
    """
    estimates = demodulate(acq, sweep, method=method, window=window)
    detection = detect_presses(acq.fsr_v, acq.rate_hz, expected=expected, units="v", fsr=fsr, **detect_kwargs)
    first = int(acq.sample_index[0])
    if detection.n_presses:
        k = int(np.argmax(detection.peak_force_n))
        onset, offset = first + int(detection.onset[k]), first + int(detection.offset[k])
    else:
        onset = offset = first + acq.n_samples
    margin = int(round(margin_s * acq.rate_hz))
    return press_features(estimates, onset, offset, margin), detection, estimates

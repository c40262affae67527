"""From a press's record to its dataset row: baseline and pressed sweeps by motion sync, FSR labels, flags.

Pure functions of the record: the baseline is every sweep that ended before the probe reached
the surface (the `contact` mark), the pressed value every sweep that lies inside the hold
(`hold_start` .. `hold_end`). The FSR labels the press (onset, offset, peak) and catches a
press the G-code commanded that never touched the skin.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from neatskin.acquisition.estimates import PairEstimates, flag_names
from neatskin.acquisition.fsr import FsrModel, PressDetection, detect_presses


@dataclass(frozen=True)
class PressValues:
    resistance_ohm: np.ndarray  # (pairs,) pressed
    baseline_ohm: np.ndarray  # (pairs,)
    delta_r_ohm: np.ndarray  # (pairs,)
    flags: tuple[str, ...]
    n_baseline: int
    n_pressed: int


def press_values(estimates: PairEstimates, marks: dict[str, int], pair_labels: list[str]) -> PressValues:
    """Per pair, the mean of the baseline sweeps and of the pressed sweeps (inf when any of them is an open
    circuit, NaN when there is none), their difference and the flags of the sweeps used."""
    start, stop = estimates.windows[..., 0], estimates.windows[..., 1]
    baseline_use = stop <= marks["contact"]
    pressed_use = (start >= marks["hold_start"]) & (stop <= marks["hold_end"])
    use = np.stack([baseline_use, pressed_use])  # (2, sweeps, pairs): baseline, pressed
    r = estimates.resistance_ohm
    count = use.sum(axis=1)
    with np.errstate(invalid="ignore"):
        total = np.where(use, r, 0.0).sum(axis=1)
    open_circuit = (use & np.isinf(r)).any(axis=1)
    mean = np.where(open_circuit, np.inf, total / np.maximum(count, 1))
    (r_b, r_p) = np.where(count > 0, mean, np.nan)
    bits = np.bitwise_or.reduce(np.where(use, estimates.flags, 0).astype(np.uint8), axis=(0, 1))
    flags: list[str] = []
    if not baseline_use.any():
        flags.append("no_baseline_sweep")
    if not pressed_use.any():
        flags.append("no_pressed_sweep")
    both_open = np.isinf(r_b) & np.isinf(r_p)
    with np.errstate(invalid="ignore"):
        delta = np.where(both_open, 0.0, r_p - r_b)
    for pair in np.flatnonzero(bits).tolist():
        flags.extend(f"{name}:{pair_labels[pair]}" for name in _flag_names(int(bits[pair])))
    return PressValues(
        r_p, r_b, delta, tuple(flags), int(baseline_use.any(axis=1).sum()), int(pressed_use.all(axis=1).sum())
    )


@functools.lru_cache(maxsize=256)
def _flag_names(bits: int) -> tuple[str, ...]:
    return flag_names(bits)


@dataclass(frozen=True)
class FsrLabel:
    onset_s: float | None
    offset_s: float | None
    peak_n: float | None
    flags: tuple[str, ...]

    @property
    def missed(self) -> bool:
        return "fsr_missed" in self.flags


def fsr_label(
    fsr_v: np.ndarray | None,
    rate_hz: float | None,
    fsr_model: FsrModel | None,
    first_sample: int,
    marks: dict[str, int],
    sample_rate_hz: float,
) -> FsrLabel:
    """Onset, offset (s after the recording began) and peak force of the press; flags when it is not one press.

    rate_hz is the FSR trace's rate (None: the DAQ's, as PressRecord.fsr_rate_hz says), sample_rate_hz the DAQ's
    (the marks are DAQ sample indices)."""
    if fsr_v is None:
        return FsrLabel(None, None, None, ())
    if rate_hz is None:
        rate_hz = sample_rate_hz
    detection: PressDetection = detect_presses(fsr_v, rate_hz, expected=1, units="v", fsr=fsr_model)
    flags = []
    if detection.n_presses == 0:
        return FsrLabel(None, None, None, ("fsr_missed",))
    if detection.n_presses > 1:
        flags.append(f"fsr_multiple:{detection.n_presses}")
    k = int(np.argmax(detection.peak_force_n))
    onset, offset = int(detection.onset[k]), int(detection.offset[k])
    hold_start = (marks["hold_start"] - first_sample) * rate_hz / sample_rate_hz
    if not onset <= hold_start < offset:
        flags.append("fsr_not_at_hold")
    return FsrLabel(onset / rate_hz, offset / rate_hz, float(detection.peak_force_n[k]), tuple(flags))

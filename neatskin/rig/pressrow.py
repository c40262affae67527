"""From a press's record to its dataset row: the FSR labels (onset, offset, peak), which also catch a press the
G-code commanded that never touched the skin.

Pure functions of the record. The row's per-pair values (baseline and pressed sweeps by motion sync, their
difference, flags) are `neatskin.acquisition.pressvalues.press_values`, reached through `PressRecord.values`
(computed where the estimates are: the skin worker's process in a dry run).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neatskin.acquisition.fsr import FsrModel, PressDetection, detect_presses


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
    window_s = baseline_window_s(fsr_v.shape[0] / rate_hz, marks, sample_rate_hz)
    detection: PressDetection = detect_presses(
        fsr_v, rate_hz, expected=1, units="v", fsr=fsr_model, baseline_window_s=window_s
    )
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


def baseline_window_s(trace_s: float, marks: dict[str, int], sample_rate_hz: float) -> float:
    """The FSR baseline's window for this press: detect_presses' own (half the trace, at least 2 s) unless the press
    may outlast it, then the press's span plus a second.

    The first baseline is a running-minimum opening, which keeps any rise longer than its window: a press longer
    than the window (a long hold) stays in the baseline and is cut into two presses off its hold. The probe is in
    the skin only between the contact mark (at the surface, about to press) and the lifted mark (back at the safe
    height), so that span bounds the press; the window is set longer, so that it reaches the unloaded part of the
    trace from anywhere in the press. A record without these marks keeps the default."""
    default_s = max(2.0, trace_s / 2)
    if "contact" not in marks or "lifted" not in marks:
        return default_s
    loaded_s = (marks["lifted"] - marks["contact"]) / sample_rate_hz
    return max(default_s, loaded_s + 1.0)

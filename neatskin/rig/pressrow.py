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

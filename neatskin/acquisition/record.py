"""What one press recorded, and the recorder seam both rigs implement (typing.Protocol).

The runner calls `begin` when the probe is parked above the target (after the travel phase's
M400), `mark(name)` after each later M400 (contact, hold start, hold end, lifted), and `end`
after the lift. Every recorder returns the same `PressRecord`; the rest of the pipeline
(demodulation, FSR detection, features) never knows which rig it came from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from neatskin.acquisition.estimates import PairEstimates


@dataclass
class PressRecord:
    """What one press recorded: per-sweep pair estimates, the FSR trace, motion-sync marks (sample indices)."""

    estimates: PairEstimates
    first_sample: int
    n_samples: int
    rate_hz: float
    marks: dict[str, int]
    fsr_v: np.ndarray | None = None
    waveforms: dict[str, np.ndarray] | None = field(default=None, repr=False)
    fsr_rate_hz: float | None = None  # rate of fsr_v (the DAQ rate unless decimated)


class Recorder(Protocol):
    """One hardware-timed acquisition of whole sweeps spanning a press, with motion-sync marks."""

    def begin(self, press_id: int, n_sweeps: int) -> None: ...

    def mark(self, name: str) -> None: ...

    def end(self) -> PressRecord: ...

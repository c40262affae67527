"""What one press recorded, and the recorder seam both rigs implement (typing.Protocol).

The runner calls `begin` when the probe is parked above the target (after the travel phase's
M400), `mark(name)` after each later M400 (contact, hold start, hold end, lifted), and `end`
after the lift. `end` returns a `PendingPress`, a future-like: its FSR trace and marks at once (the runner's
retry decision needs the label before the next press), its whole `PressRecord` by `result()`. A recorder that
computes everything in `end` returns the `PressRecord` itself, an already-done future; the dry run's skin
worker returns its ticket (neatskin.sim.skinworker.DeferredRecord), whose estimates come once the press is
`keep()`-ed. The rest of the pipeline (demodulation, FSR detection, features) never knows which rig it came from.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from neatskin.acquisition.estimates import PairEstimates
from neatskin.acquisition.pressvalues import PressValues, press_values


@dataclass
class PressRecord:
    """What one press recorded: per-sweep pair estimates, the FSR trace, motion-sync marks (sample indices)."""

    estimates: PairEstimates | None  # None: only the values came back (the dry run's skin worker, values_only)
    first_sample: int
    n_samples: int
    rate_hz: float
    marks: dict[str, int]
    fsr_v: np.ndarray | None = None
    waveforms: dict[str, np.ndarray] | None = field(default=None, repr=False)
    fsr_rate_hz: float | None = None  # rate of fsr_v (the DAQ rate unless decimated)
    # the row's per-pair values, when computed where the estimates were (the dry run's skin worker); else None
    # and `values` computes them here: the same function (acquisition.pressvalues), the same bits
    computed_values: PressValues | None = field(default=None, repr=False)

    def values(self, pair_labels: Sequence[str]) -> PressValues:
        """The row's per-pair values (neatskin.acquisition.pressvalues.press_values of the estimates and marks)."""
        if self.computed_values is not None:
            return self.computed_values
        if self.estimates is None:
            raise RuntimeError("a press record with neither estimates nor values")
        return press_values(self.estimates, self.marks, pair_labels)

    # an already-done PendingPress: nothing is deferred, so keeping it starts nothing and its result is itself
    def keep(self) -> PressRecord:
        return self

    def done(self) -> bool:
        return True

    def result(self) -> PressRecord:
        return self


class PendingPress(Protocol):
    """A press recorded, its pair estimates possibly still being computed: the FSR trace and marks now
    (PressRecord's fields of those names), the whole record by `result()`."""

    @property
    def first_sample(self) -> int: ...

    @property
    def rate_hz(self) -> float: ...

    @property
    def marks(self) -> dict[str, int]: ...

    @property
    def fsr_v(self) -> np.ndarray | None: ...

    @property
    def fsr_rate_hz(self) -> float | None: ...

    def keep(self) -> PendingPress:
        """The press is kept (not retried): start whatever is deferred. Once; later calls change nothing."""
        ...

    def done(self) -> bool:
        """Whether `result()` answers without waiting."""
        ...

    def result(self) -> PressRecord:
        """The whole record; waits (with a deadline) for what is deferred, after `keep()`."""
        ...


class Recorder(Protocol):
    """One hardware-timed acquisition of whole sweeps spanning a press, with motion-sync marks."""

    def begin(self, press_id: int, n_sweeps: int) -> None: ...

    def mark(self, name: str) -> None: ...

    def end(self) -> PendingPress: ...

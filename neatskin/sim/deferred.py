"""A press whose pair estimates are computed elsewhere: the job the skin worker is given, and the record that
waits for its answer (the dry run's `PendingPress`, neatskin.acquisition.record).

The recorder (neatskin.sim.recorder) makes these; the skin worker (neatskin.sim.skinworker) is one
`EstimateQueue` answering them in order. Neither module imports the other's side of this seam.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from neatskin.acquisition.estimates import PairEstimates
from neatskin.acquisition.pressvalues import PressValues
from neatskin.acquisition.record import PressRecord


@dataclass(frozen=True)
class EstimateJob:
    """What the worker needs of one press: its id (the random stream, the conditions) and its moves."""

    press_id: int
    n_sweeps: int
    segments: tuple  # sim.motion.Segment of the press, on its own clock (DryProbe.segments after load)
    # the press's motion-sync marks (DAQ sample indices): given, the worker also computes the row's per-pair values
    # (acquisition.pressvalues) beside the estimates, off the main process, the campaign's critical path
    marks: dict[str, int] | None = None
    # with marks: answer the values alone (PressValues, ~1 kB), not the estimates too (~24 kB pickled a paper press,
    # which the main process never reads): less pickling on both sides of the pipe
    values_only: bool = False


@dataclass(frozen=True)
class Estimated:
    """A worker's answer to a job with marks: the press's estimates and the row's per-pair values of them."""

    estimates: PairEstimates
    values: PressValues


class EstimateQueue(Protocol):
    """Where a deferred press's estimates come from, in the order the presses were submitted (SkinWorker)."""

    def submit(self, job: EstimateJob) -> int:
        """Queue a press; returns its ticket."""
        ...

    def result(self, ticket: int, press_id: int) -> PairEstimates | Estimated | PressValues:
        """The estimates of the press with this ticket (with its values when its job had marks; the values alone when
        it asked for them alone), the next one due."""
        ...


@dataclass
class DeferredRecord:
    """A press recorded except its pair estimates, the dry run's PendingPress (neatskin.acquisition.record): the
    FSR trace and marks (PressRecord's fields of those names) now, the estimates from the worker once the press
    is `keep()`-ed, by `result()`."""

    first_sample: int
    n_samples: int
    rate_hz: float
    marks: dict[str, int]
    fsr_v: np.ndarray | None
    fsr_rate_hz: float
    job: EstimateJob
    worker: EstimateQueue = field(repr=False)
    ticket: int | None = None
    _record: PressRecord | None = field(default=None, repr=False)

    @property
    def press_id(self) -> int:
        return self.job.press_id

    def keep(self) -> DeferredRecord:
        """Send the press to the worker (once): only a press that is kept costs the worker anything."""
        if self.ticket is None:
            self.ticket = self.worker.submit(self.job)
        return self

    def done(self) -> bool:
        """Whether the worker's estimates are in (`result()` taken once); the worker's pipe is not polled."""
        return self._record is not None

    def result(self) -> PressRecord:
        """The whole record, waiting for the worker's estimates (with a deadline)."""
        if self._record is None:
            if self.ticket is None:
                raise RuntimeError(f"press {self.press_id}: result() before keep()")
            answer = self.worker.result(self.ticket, self.press_id)
            estimates: PairEstimates | None
            if isinstance(answer, PressValues):
                estimates, values = None, answer
            elif isinstance(answer, Estimated):
                estimates, values = answer.estimates, answer.values
            else:
                estimates, values = answer, None
            self._record = PressRecord(
                estimates,
                self.first_sample,
                self.n_samples,
                self.rate_hz,
                self.marks,
                self.fsr_v,
                None,
                self.fsr_rate_hz,
                values,
            )
        return self._record

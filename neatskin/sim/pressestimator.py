"""What the dry run's skin worker computes for a press: the simulated DAQ reading a probe given the press's moves.

`PressEstimator` is the estimator `neatskin.sim.dryscene.skin_estimator` builds inside the worker process
(`neatskin.sim.skinworker` carries the jobs and answers and knows no skin): per `EstimateJob` the pair
estimates of `features_estimates`, the same function the inline recorder calls on the same random stream keyed
by (seed, press_id), and, for a job with marks, the row's per-pair values (`press_values`).
"""

from __future__ import annotations

from typing import Any

from neatskin.acquisition.estimates import PairEstimates
from neatskin.acquisition.pressvalues import PressValues, press_values
from neatskin.sim.deferred import Estimated, EstimateJob
from neatskin.sim.dryprobe import DryProbe
from neatskin.sim.recorder import PRESS_SLOT_S, features_estimates


class PressEstimator:
    """The worker's side: a probe with no printer (it is given each press's moves), the simulated DAQ reading it;
    for a job with marks, also the row's per-pair values (`pair_labels`: the layout's pairs, which name the flags)."""

    def __init__(
        self,
        daq: Any,
        sweep: Any,
        probe: DryProbe,
        *,
        seed: int,
        method: str,
        window: int,
        pair_labels: tuple[str, ...] | None = None,
    ) -> None:
        self.daq, self.sweep, self.probe = daq, sweep, probe
        self.seed, self.method, self.window = seed, method, window
        self.pair_labels = pair_labels

    def __call__(self, job: EstimateJob) -> PairEstimates | Estimated | PressValues:
        estimates = self._estimates(job)
        if job.marks is None or self.pair_labels is None:
            return estimates
        values = press_values(estimates, job.marks, self.pair_labels)
        return values if job.values_only else Estimated(estimates, values)

    def _estimates(self, job: EstimateJob) -> PairEstimates:
        self.probe.load_segments(job.press_id, list(job.segments), job.press_id * PRESS_SLOT_S)
        return features_estimates(
            self.daq,
            self.sweep,
            job.press_id,
            job.n_sweeps,
            seed=self.seed,
            method=self.method,
            window=self.window,
        )

"""The row's per-pair values computed in the skin worker (a job with marks) are press_values of the estimates it
sends with them, exactly; a record carrying them gives them without computing, one without computes the same.
(That a worker campaign's rows equal the inline run's, every value and flag: test_dry_worker.)"""

import numpy as np
from conftest import PROTOCOLS

from neatskin.acquisition.pressvalues import press_values
from neatskin.acquisition.record import PressRecord
from neatskin.rig.dryrig import dry_scene
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.sim.deferred import DeferredRecord, Estimated, EstimateJob
from neatskin.sim.dryscene import skin_estimator


def _estimator():
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    plan = build_plan(protocol)
    return skin_estimator(dry_scene(protocol, plan), plan.sweep), plan, [p.label for p in protocol.layout.pairs]


def _marks(windows: np.ndarray) -> dict[str, int]:
    stops, starts = windows[:, :, 1].max(axis=1), windows[:, :, 0].min(axis=1)
    return {"contact": int(stops[5]), "hold_start": int(starts[10]), "hold_end": int(stops[20]), "lifted": 0}


class _Queue:
    """An EstimateQueue answering from a list (the worker's answers, in order)."""

    def __init__(self, answers):
        self.answers, self.jobs = list(answers), []

    def submit(self, job):
        self.jobs.append(job)
        return len(self.jobs) - 1

    def result(self, ticket, press_id):
        return self.answers[ticket]


def test_a_job_with_marks_gets_the_values_of_the_estimates_sent_with_them():
    estimate, plan, labels = _estimator()
    plain = estimate(EstimateJob(17, plan.n_sweeps, ()))
    marks = _marks(plain.windows)
    answer = estimate(EstimateJob(17, plan.n_sweeps, (), marks))
    assert isinstance(answer, Estimated) and not isinstance(plain, Estimated)
    assert np.array_equal(answer.estimates.resistance_ohm, plain.resistance_ohm)  # the same stream, the same bits
    want = press_values(plain, marks, labels)
    got = answer.values
    assert got.n_baseline == want.n_baseline == 6 and got.n_pressed == want.n_pressed == 11
    for name in ("resistance_ohm", "baseline_ohm", "delta_r_ohm"):
        assert np.array_equal(getattr(got, name), getattr(want, name), equal_nan=True), name
    assert got.flags == want.flags


def test_a_record_gives_the_values_it_carries_and_computes_them_when_it_carries_none():
    estimate, plan, labels = _estimator()
    plain = estimate(EstimateJob(3, plan.n_sweeps, ()))
    marks = _marks(plain.windows)
    computed = press_values(plain, marks, labels)
    sentinel = computed.__class__(computed.resistance_ohm * 0, computed.baseline_ohm, computed.delta_r_ohm, (), 0, 0)
    job = EstimateJob(3, plan.n_sweeps, (), marks)
    carried = DeferredRecord(0, 1, 1.0, marks, None, 1.0, job, _Queue([Estimated(plain, sentinel)])).keep()
    assert carried.result().values(labels) is sentinel  # not recomputed from the estimates
    bare = DeferredRecord(0, 1, 1.0, marks, None, 1.0, job, _Queue([plain])).keep()
    assert np.array_equal(bare.result().values(labels).resistance_ohm, computed.resistance_ohm, equal_nan=True)
    inline = PressRecord(plain, 0, 1, 1.0, marks)
    assert inline.values(labels).flags == computed.flags
    assert np.array_equal(inline.values(labels).delta_r_ohm, computed.delta_r_ohm, equal_nan=True)


def test_a_values_only_job_gets_the_values_alone_and_its_record_gives_them():
    """values_only (what the dry run's recorder asks): the worker answers the same PressValues without the
    estimates, and the deferred record built on that answer gives those values and holds no estimates."""
    estimate, plan, labels = _estimator()
    plain = estimate(EstimateJob(9, plan.n_sweeps, ()))
    marks = _marks(plain.windows)
    alone = estimate(EstimateJob(9, plan.n_sweeps, (), marks, values_only=True))
    want = press_values(plain, marks, labels)
    assert not isinstance(alone, Estimated) and alone.flags == want.flags
    for name in ("resistance_ohm", "baseline_ohm", "delta_r_ohm"):
        assert np.array_equal(getattr(alone, name), getattr(want, name), equal_nan=True), name
    job = EstimateJob(9, plan.n_sweeps, (), marks, values_only=True)
    record = DeferredRecord(0, 1, 1.0, marks, None, 1.0, job, _Queue([alone])).keep().result()
    assert record.estimates is None and record.values(labels) is alone

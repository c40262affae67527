"""Work the skin worker does beside the presses (SkinWorker.aside): computed in the worker's process while the
presses' answers keep coming in order; its error is one HardwareError, its warnings reach the caller; the dry
run's physical limit computed there on the worker's skin and DAQ is the main process's table, exactly. And the
pinch kernel is read without importing pandas (what a dry run's start and its worker's used to pay for)."""

import functools
import os
import subprocess
import sys
import warnings

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS

from neatskin.errors import HardwareError
from neatskin.rig.dryrig import _physical_limit_table_in_worker, dry_scene
from neatskin.rig.physlimit import physical_limit_table
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.sim.dryscene import dry_daq, dry_probe, dry_skin, skin_estimator
from neatskin.sim.skinworker import EstimateJob, SkinWorker
from neatskin.skin.kernel import packaged_kernel_path, read_kernel


def echo_estimator():
    def echo(job):
        return ("estimates of", job.press_id, os.getpid())

    return echo


def pid_and_square(value, estimator):
    return os.getpid(), value * value, estimator(EstimateJob(-1, 1, ()))[1]


def broken(estimator):
    raise ZeroDivisionError("no table today")


def warns(estimator):
    np.log(np.zeros(1))  # RuntimeWarning: divide by zero
    warnings.warn("the worker's own words", UserWarning, stacklevel=1)
    return "done"


def test_an_aside_runs_in_the_worker_while_the_presses_answer_in_order():
    worker = SkinWorker(echo_estimator).start()
    try:
        first = worker.submit(EstimateJob(0, 1, ()))
        table = worker.aside(functools.partial(pid_and_square, 7))
        tickets = [worker.submit(EstimateJob(k, 1, ())) for k in range(1, 6)]
        assert worker.result(first, 0)[:2] == ("estimates of", 0)
        pid, square, seen = table()  # read before the presses after it: they wait in order
        assert (pid, square, seen) == (worker.pid, 49, -1) and pid != os.getpid()
        assert [worker.result(t, k)[1] for k, t in zip(range(1, 6), tickets)] == [1, 2, 3, 4, 5]
    finally:
        worker.close()


def test_an_aside_before_any_press_is_sent_when_its_result_is_asked():
    worker = SkinWorker(echo_estimator).start()
    try:
        assert worker.aside(functools.partial(pid_and_square, 3))()[1] == 9
    finally:
        worker.close()


def test_an_aside_that_fails_is_one_hardware_error_and_the_presses_go_on():
    worker = SkinWorker(echo_estimator).start()
    try:
        result = worker.aside(broken)
        ticket = worker.submit(EstimateJob(4, 1, ()))
        with pytest.raises(HardwareError, match="beside the presses: ZeroDivisionError: no table today"):
            result()
        assert worker.result(ticket, 4)[1] == 4
    finally:
        worker.close()


def test_an_asides_warnings_reach_the_caller():
    worker = SkinWorker(echo_estimator).start()
    try:
        result = worker.aside(warns)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert result() == "done"
    finally:
        worker.close()
    shown = {(w.category, str(w.message)) for w in caught}
    assert (UserWarning, "the worker's own words") in shown
    assert (RuntimeWarning, "divide by zero encountered in log") in shown


def test_the_physical_limit_of_the_workers_skin_is_the_main_processes_table():
    """The worker builds its skin and DAQ from the same DryScene (with the conditions the main process's
    force-only probe leaves out): the bound depends on neither, so the two tables are equal, not close."""
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    main = physical_limit_table(protocol, plan, skin, dry_daq(dry, dry_probe(dry, skin, list, force_only=True)))
    worker = _physical_limit_table_in_worker(protocol, plan, skin_estimator(dry, plan.sweep))
    assert main.num_rows > 0 and main.equals(worker)


def test_the_pinch_kernel_is_read_without_pandas_and_as_parquet_holds_it():
    code = (
        "import sys; from neatskin.skin.kernel import read_kernel, packaged_kernel_path; "
        "read_kernel(packaged_kernel_path()); print('pandas' in sys.modules)"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "False"
    kernel, table = read_kernel(packaged_kernel_path()), pq.read_table(packaged_kernel_path())
    shape = kernel.area_ratio.shape
    for name, got in (("area_ratio", kernel.area_ratio), ("force_n", kernel.force_n), *kernel.extra.items()):
        want = table.column(name).to_numpy().reshape(shape)
        assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True), name
    assert np.array_equal(kernel.offsets_mm, np.unique(table.column("offset_mm").to_numpy()))

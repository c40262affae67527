"""The report's task runner: outputs by key whatever the order, costliest first in parallel, work done meanwhile;
a report in processes gives the same numbers as one in this process."""

import json
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from proctree import alive, children

from neatskin.baselines.inversion import _diverse_starts
from neatskin.baselines.models import fit_cost_s
from neatskin.baselines.report import run_baselines
from neatskin.baselines.tasks import Task, costliest_first, run_tasks
from neatskin.layout import load_layout
from neatskin.skin.synthetic import synthetic_presses

REPO = Path(__file__).resolve().parent.parent
PAPER_SKIN = REPO / "protocols" / "skins" / "paper.toml"


def _square(x: int) -> int:
    return x * x


def test_costliest_first_keeps_the_given_order_among_equal_costs():
    tasks = [Task(k, c, _square, (k,)) for k, c in [(1, 0.5), (2, 3.0), (3, 0.5), (4, 3.0), (5, 1.0)]]
    assert [t.key for t in costliest_first(tasks)] == [2, 4, 5, 1, 3]


def test_serial_tasks_run_in_the_given_order_after_the_meanwhile_work():
    calls = []

    def record(x):
        calls.append(x)
        return -x

    tasks = [Task(("t", k), cost, record, (k,)) for k, cost in [(0, 1.0), (1, 9.0), (2, 5.0)]]
    progress = []
    out = run_tasks(tasks, meanwhile=lambda: calls.append("meanwhile"), progress=lambda d, t: progress.append((d, t)))
    assert calls == ["meanwhile", 0, 1, 2]
    assert out == {("t", 0): 0, ("t", 1): -1, ("t", 2): -2}
    assert progress == [(1, 3), (2, 3), (3, 3)]


def test_in_a_pool_the_costliest_task_starts_first():
    started = []
    lock = threading.Lock()

    def record(x):
        with lock:
            started.append(x)
        return x

    tasks = [Task(k, cost, record, (k,)) for k, cost in [("cheap", 0.1), ("dear", 10.0), ("middle", 1.0)]]
    meanwhile = []
    out = run_tasks(tasks, n_jobs=1, backend="threading", meanwhile=lambda: meanwhile.append(1))
    assert started == ["dear", "middle", "cheap"]
    assert out == {"cheap": "cheap", "dear": "dear", "middle": "middle"}
    assert meanwhile == [1]


def test_processes_give_every_output_by_key():
    tasks = [Task(("sq", k), float(k % 3), _square, (k,)) for k in range(12)]
    assert run_tasks(tasks, n_jobs=2) == {("sq", k): k * k for k in range(12)}


def test_duplicate_keys_are_refused():
    with pytest.raises(ValueError, match="unique"):
        run_tasks([Task(1, 0.0, _square, (1,)), Task(1, 0.0, _square, (2,))])


def test_fit_costs_order_the_models_as_measured():
    order = sorted(
        ["ridge", "knn", "kernel_ridge", "extra_trees", "mlp", "lm_network"], key=lambda n: -fit_cost_s(n, 2700)
    )
    assert order[0] == "mlp" and order[-2:] == ["ridge", "knn"]  # 50 trees fit in about half the MLP's time
    assert fit_cost_s("kernel_ridge", 5400) == pytest.approx(4 * fit_cost_s("kernel_ridge", 2700))
    assert fit_cost_s("mlp", 5400) == pytest.approx(2 * fit_cost_s("mlp", 2700))


def test_diverse_starts_are_those_of_the_norm_based_rule():
    rng = np.random.default_rng(3)
    grid_xy = np.round(rng.uniform(-0.5, 30.5, (400, 2)), 1)  # ties at exactly the separation happen on a grid
    grid_dr = rng.normal(size=(400, 6))
    dr = rng.normal(size=(70, 6))
    got = _diverse_starts(grid_xy, grid_dr, dr, 3, 3.0, chunk=32)
    g2 = np.einsum("gp,gp->g", grid_dr, grid_dr)
    expected = np.empty_like(got)
    for i, row in enumerate(dr):
        dist = g2 - 2.0 * grid_dr @ row
        for j in range(3):
            best = int(np.argmin(dist))
            expected[i, j] = best
            dist[np.linalg.norm(grid_xy - grid_xy[best], axis=1) < 3.0] = np.inf
    np.testing.assert_array_equal(got, expected)
    assert all(len(set(r)) == 3 for r in got.tolist())


def test_a_report_in_processes_equals_one_in_this_process(tmp_path):
    df = synthetic_presses(load_layout(PAPER_SKIN), 10, 8, seed=2, noise_ohm=1.0)
    df.insert(0, "campaign", "synthetic")
    folder = tmp_path / "ds"
    folder.mkdir()
    df.to_parquet(folder / "presses.parquet", index=False)
    (folder / "manifest.json").write_text(json.dumps({"layout": {"path": str(PAPER_SKIN)}, "status": "complete"}))
    kwargs = dict(split="both", models=["ridge", "knn", "lm_network", "inversion"], n_repeats=2, progress=False)
    with pytest.warns(UserWarning):
        here = run_baselines(folder, out=tmp_path / "here", n_jobs=1, **kwargs)
    with pytest.warns(UserWarning):
        pool = run_baselines(folder, out=tmp_path / "pool", n_jobs=2, **kwargs)
    timing = ["fit_time_s", "predict_time_per_sample_us"]
    assert here.table["split"].unique().tolist() == ["grouped", "random", "design"]
    assert len(here.table) == 12  # 3 learners and the inversion on each split
    pd.testing.assert_frame_equal(here.table.drop(columns=timing), pool.table.drop(columns=timing))
    inv_here = next(r for r in here.results if r.model == "inversion" and r.split == "grouped")
    inv_pool = next(r for r in pool.results if r.model == "inversion" and r.split == "grouped")
    np.testing.assert_array_equal(inv_here.y_pred_mm, inv_pool.y_pred_mm)


def _pid_and_blas_threads(key: str, sleep_s: float, flag: str, hold_for: str = "") -> tuple[str, int, list[int]]:
    """The task's key, its process and BLAS threads; it touches `flag` and then, given `hold_for`, holds until that
    file exists (a cap of 60 s), so a test can decide which lane takes which task without racing the scheduler."""
    import os
    import time

    from threadpoolctl import threadpool_info

    time.sleep(sleep_s)
    if flag:
        Path(flag).touch()
    if hold_for:
        _wait_for(Path(hold_for))
    return key, os.getpid(), sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})


def _wait_for(path: Path, deadline_s: float = 60.0) -> None:
    import time

    end = time.monotonic() + deadline_s
    while not path.exists() and time.monotonic() < end:
        time.sleep(0.01)
    assert path.exists(), "the worker never took the costliest task"


def test_this_process_is_a_lane_taking_the_cheap_end_and_the_worker_ends_with_the_tasks(tmp_path):
    import multiprocessing
    import os

    import numpy  # noqa: F401  (loads the BLAS whose threads the lanes set)

    others = set(multiprocessing.active_children())  # an earlier test's pool in this process, e.g. loky's
    dear, cheapest = tmp_path / "dear-started", tmp_path / "cheap0-done"
    # the worker holds the costliest task until the cheapest has run: a worker done at once could otherwise take
    # every cheap task before this process wakes (seen once in CI, under load)
    tasks = [Task("dear", 10.0, _pid_and_blas_threads, ("dear", 0.0, str(dear), str(cheapest)))]
    tasks += [Task("cheap0", 0.0, _pid_and_blas_threads, ("cheap0", 0.0, str(cheapest)))]
    tasks += [Task(f"cheap{k}", 0.1 * k, _pid_and_blas_threads, (f"cheap{k}", 0.0, "")) for k in range(1, 4)]
    # meanwhile waits until the worker has the costliest task, so this process's share is decided by the order
    out = run_tasks(tasks, n_jobs=2, meanwhile=lambda: _wait_for(dear))
    assert set(out) == {t.key for t in tasks}
    assert out["dear"][1] != os.getpid()  # the costliest went to the worker
    assert out["cheap0"][1] == os.getpid()  # the cheapest was this process's first
    assert set(multiprocessing.active_children()) <= others  # no worker outlives the tasks (nor holds their memory)
    threads = max((os.cpu_count() or 1) // 2, 1)  # as joblib gives each of 2 workers
    assert {tuple(v[2]) for v in out.values()} == {(threads,)}  # the same BLAS threads in either lane


def _fails(x: int) -> int:
    if x == 3:
        raise ArithmeticError(f"task {x} failed")
    return x


def test_a_task_failing_in_a_worker_is_raised_here_and_no_worker_is_left():
    import multiprocessing

    others = set(multiprocessing.active_children())
    tasks = [Task(k, 10.0 if k == 3 else 0.0, _fails, (k,)) for k in range(6)]  # 3 is the dearest: a worker's
    with pytest.raises(ArithmeticError, match="task 3 failed"):
        run_tasks(tasks, n_jobs=2)
    assert set(multiprocessing.active_children()) <= others


def test_a_fit_worker_ends_when_the_report_is_killed_outright(tmp_path):
    """A report killed by SIGKILL leaves no fit worker behind: the spawned worker (here in a 120 s task) ends
    within seconds of its parent, where it used to wait forever (neatskin.orphans)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = (
        "import time\n"
        "from neatskin.baselines.tasks import Task, run_tasks\n"
        "run_tasks([Task(('a',), 2.0, time.sleep, (120,)), Task(('b',), 1.0, time.sleep, (120,))], n_jobs=2)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    proc = subprocess.Popen([sys.executable, "-c", script], env=env)

    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not children(proc.pid, b"spawn_main"):
            time.sleep(0.05)
        started = children(proc.pid, b"spawn_main")
        assert started, "run_tasks with 2 lanes spawns a worker"
        time.sleep(1.0)  # the worker has taken its task
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(alive(pid) for pid in started):
            time.sleep(0.1)
        left = [pid for pid in started if alive(pid)]
        for pid in left:
            os.kill(pid, signal.SIGKILL)
        assert not left, "the killed report's fit worker is left running"
    finally:
        if proc.poll() is None:
            proc.kill()

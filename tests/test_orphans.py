"""Processes a run starts end with it: joblib's loky workers of a design study, a validation or a campaign forecast
(`neatskin.orphans.watched_parallel`), when the run is killed outright."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from proctree import alive, children

REPO = Path(__file__).resolve().parent.parent

# busy: two workers each in a 120 s task, as a design study's candidates keep them busy for minutes; idle: two
# workers done with their tasks while the run goes on (loky keeps them for the next call, 300 s)
SCRIPT = """
import time
from joblib import Parallel, delayed
from neatskin.orphans import watched_parallel
parallel = {make}
if {busy}:
    parallel(delayed(time.sleep)(120) for _ in range(2))
else:
    parallel(delayed(time.sleep)(0.5) for _ in range(2))
    time.sleep(120)
"""


def _workers_left_after_a_kill(make: str, wait_s: float, busy: bool) -> list[int]:
    """Run SCRIPT with `make` as its Parallel, SIGKILL it once both workers run, and return those still alive
    `wait_s` later (the survivors are killed before returning)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT.format(make=make, busy=busy)], env=env)
    started: list[int] = []
    trackers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(started) < 2:
            started = children(proc.pid, b"LokyProcess")  # not its resource tracker
            time.sleep(0.05)
        assert len(started) == 2, f"two loky workers start ({started})"
        time.sleep(1.0)  # each has taken its task (busy), or finished it (idle)
        trackers = children(proc.pid, b"resource_tracker")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and any(alive(pid) for pid in started):
            time.sleep(0.1)
        return [pid for pid in started if alive(pid)]
    finally:
        if proc.poll() is None:
            proc.kill()
        for pid in started:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        # joblib's resource tracker (also its child) removes the run's semaphores and memmapping folders from
        # /dev/shm once its parent is gone: waited for, so no test run leaves them behind
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(alive(pid) for pid in trackers):
            time.sleep(0.1)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads the process tree from Linux's /proc")
@pytest.mark.parametrize("busy", [True, False], ids=["busy", "idle"])
def test_a_killed_runs_joblib_workers_end_with_it(busy):
    # watched: both workers end within seconds of their parent (the watch looks every 0.5 s)
    assert _workers_left_after_a_kill("watched_parallel(2)", wait_s=10.0, busy=busy) == []
    # the negative control: joblib's own Parallel leaves them running their tasks for nobody, or idle for 300 s
    assert len(_workers_left_after_a_kill("Parallel(n_jobs=2)", wait_s=3.0, busy=busy)) == 2

"""`campaign check` stopped while it solves a missing pinch kernel (minutes of CPU in joblib's loky workers): Ctrl-C,
SIGTERM and SIGHUP end it as they end `campaign run` (exit 130) with one line, no traceback and no resource-tracker
warning, its workers gone and nothing cached. 942188f died of SIGTERM (exit -15) leaving its workers solving, or
("leaked semlock objects") warned when the signal reached the whole group. The solve is stood in for by a worker
that records its pid and sleeps (pickled by value from the script's __main__, as loky sends it)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_electrical_pressed import _paper_at
from test_run_rails_warning import _running

STANDIN = """
import os, sys, time
import neatskin.skin.kernel as kernel

def slow_solve(spec, task):  # one solve of the kernel: minutes; here until the test is done
    with open({pids!r}, "a") as f:
        f.write(f"{{os.getpid()}}\\n")
    time.sleep(1000)

kernel._solve_task = slow_solve
from neatskin.cli import main
sys.exit(main(["campaign", "check", {protocol!r}]))
"""


def _group(pgid: int) -> list[int]:
    """The live processes of process group `pgid`."""
    alive = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(stat.parent.name))
    return alive


@pytest.mark.timeout(180)
@pytest.mark.parametrize(
    "signum, group",
    [(signal.SIGINT, True), (signal.SIGTERM, False), (signal.SIGTERM, True), (signal.SIGHUP, False)],
    ids=["ctrl-c", "sigterm", "sigterm-group", "sighup"],
)
def test_a_stopped_kernel_solve_ends_with_one_line_and_no_workers(tmp_path, signum, group):
    path = _paper_at(tmp_path, "0.0002")
    path.write_text(path.read_text().replace("probe_diameter_mm = 5.5", "probe_diameter_mm = 6.0"))  # none packaged
    pids, out, err = tmp_path / "workers.pid", tmp_path / "out", tmp_path / "err"
    script = tmp_path / "standin.py"
    script.write_text(STANDIN.format(pids=str(pids), protocol=str(path)))
    env = {**os.environ, "NEATSKIN_CACHE": str(tmp_path / "cache")}
    with out.open("w") as stdout, err.open("w") as stderr:  # files: a worker left alive would hold a pipe open
        check = subprocess.Popen(
            [sys.executable, str(script)], stdout=stdout, stderr=stderr, env=env, start_new_session=True
        )
    try:
        deadline = time.monotonic() + 120.0
        while not (pids.exists() and len(pids.read_text().split()) == 2) and time.monotonic() < deadline:
            assert check.poll() is None, err.read_text()
            time.sleep(0.1)
        workers = [int(pid) for pid in pids.read_text().split()]
        assert len(workers) == 2 and "first solving the finite-element pinch kernel" in out.read_text()
        (os.killpg if group else os.kill)(check.pid, signum)  # a terminal's Ctrl-C reaches the whole group
        assert check.wait(60) == 130
        # the workers end as the check stops, /proc shows it a moment later; the resource trackers (the group's
        # last processes) would print their warnings as they end, after the check's exit
        deadline = time.monotonic() + 30.0
        while (any(map(_running, workers)) or _group(check.pid)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(map(_running, workers)) and not _group(check.pid)
        assert err.read_text() == (
            "neatskin: interrupted: the pinch kernel's solve was stopped, nothing cached: `neatskin campaign check` "
            "starts it again\n"
        )
        assert not list((tmp_path / "cache").glob("kernels/*.parquet"))
    finally:
        try:
            os.killpg(check.pid, signal.SIGKILL)  # whatever of this test's group is left
        except ProcessLookupError:
            pass

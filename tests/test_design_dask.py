"""A study on a real 2-worker distributed.LocalCluster: the same numbers as a local run, and every candidate exactly
once in the results when a worker is killed mid-study."""

import os
import signal
import sys

import pandas as pd
import pytest

from neatskin.design.candidates import expand
from neatskin.design.runner import run_study
from neatskin.design.study import study_from_dict
from neatskin.errors import ConfigError

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

distributed = pytest.importorskip("distributed")

STUDY = {
    "study": {"name": "dask", "seed": 3, "press_grid": 8},
    "layouts": {"sizes": [[3, 3], [4, 3], [4, 4]], "pitch_mm": [15.0]},
    "electrodes": {"counts": [4, 5], "strategies": ["boundary", "optimised"], "restarts": 1},
}


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
    ) as local:
        yield local


def test_dask_run_agrees_with_a_local_run_and_survives_a_killed_worker(tmp_path, cluster):
    study = study_from_dict(STUDY, source="<dask test>")
    total = len(expand(study))
    local = run_study(study, tmp_path / "local", pngs=False)
    on_dask = run_study(study, tmp_path / "dask", scheduler="dask", address=cluster.scheduler_address, pngs=False)
    pd.testing.assert_frame_equal(local, on_dask, check_exact=True)

    with distributed.Client(cluster.scheduler_address, set_as_default=False) as client:
        pids = client.run(os.getpid)
    killed = []

    def kill_one_worker(result):
        if not killed:
            pid = next(iter(pids.values()))
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    again = run_study(
        study,
        tmp_path / "killed",
        scheduler="dask",
        address=cluster.scheduler_address,
        pngs=False,
        on_result=kill_one_worker,
    )
    assert killed, "no result arrived"
    assert len(again) == total and again["candidate_id"].is_unique
    assert len(list((tmp_path / "killed" / "parts").glob("*.parquet"))) == total
    pd.testing.assert_frame_equal(local, again, check_exact=True)


def test_dask_needs_an_address_and_a_reachable_scheduler(tmp_path):
    study = study_from_dict(STUDY, source="<dask test>")
    with pytest.raises(ConfigError, match="needs the cluster's address"):
        run_study(study, tmp_path / "a", scheduler="dask")
    with pytest.raises(ConfigError, match="cannot reach the Dask scheduler") as info:
        run_study(study, tmp_path / "b", scheduler="dask", address="tcp://127.0.0.1:9", connect_timeout_s=1.0)
    assert info.value.field == "--address"


def test_nothing_outside_a_dask_run_imports_dask(tmp_path):
    import subprocess

    code = (
        "import sys\n"
        "from neatskin.design.runner import run_study\n"
        "from neatskin.design.study import study_from_dict\n"
        f"run_study(study_from_dict({STUDY!r}), {str(tmp_path / 'o')!r}, pngs=False)\n"
        "import neatskin.cli; neatskin.cli.build_parser()\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')], 'dask imported'\n"
    )
    env = {**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(os.path.abspath(__file__)))}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr

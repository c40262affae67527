"""Fault injection: two processes on one campaign folder. A second run or resume gets one clear error naming
the holder's PID; a lock left by a killed process is taken over; info tells running from crashed; merge
refuses a running or incomplete campaign unless asked (and records that it was asked)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from conftest import PROTOCOLS, REPO

from neatskin.datasets.curate import describe, merge
from neatskin.datasets.lock import CampaignLock, lock_state
from neatskin.datasets.reader import read_metadata, read_presses
from neatskin.errors import DataError
from neatskin.rig.runner import resume_campaign

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out


@pytest.fixture(scope="module")
def long_protocol(tmp_path_factory):
    """The smoke protocol with 120 presses (features only): a campaign that runs long enough to meet."""
    root = tmp_path_factory.mktemp("protocols")
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("repeats = 2", "repeats = 20").replace("waveforms = true", "waveforms = false")
    path = root / "long.toml"
    path.write_text(text.replace('signal = "waveforms"', 'signal = "features"'))
    return path


def _start(protocol, folder):
    return subprocess.Popen(
        [sys.executable, "-m", "neatskin", "campaign", "run", str(protocol), "--dry-run", "--out", str(folder)]
        + ["--no-report", "--quiet"],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_presses(folder, n=1, timeout_s=60):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if len(list((folder / "presses").glob("part-*.parquet"))) >= n:
            return
        time.sleep(0.02)
    raise AssertionError(f"no {n} presses in {folder} within {timeout_s} s")


@pytest.mark.timeout(240)
def test_second_run_and_resume_are_refused_while_a_campaign_runs(long_protocol, tmp_path):
    # 1,200 presses: the first run must still hold the folder when the second starts (at 120 an idle machine
    # finished it in between, and the second was told the folder holds files, with no run named)
    longer = long_protocol.with_name("longer.toml")
    longer.write_text(long_protocol.read_text().replace("repeats = 20", "repeats = 200"))
    folder = tmp_path / "c"
    first = _start(longer, folder)
    try:
        _wait_for_presses(folder)
        assert describe(folder)["status"] == f"running ({lock_state(folder)[1]})"
        assert lock_state(folder)[1].pid == first.pid

        second = _start(longer, folder)
        assert second.wait(60) == 3
        assert f"another run holds this folder (PID {first.pid}" in second.stderr.read()

        with pytest.raises(DataError, match=f"in use by PID {first.pid}") as err:
            resume_campaign(folder, progress=False, report=False)
        assert err.value.file == str(folder / "campaign.lock") and f"kill {first.pid}" in err.value.problems[0].fix

        with pytest.raises(DataError, match="not complete") as err:
            merge([folder, folder.parent / "other"], tmp_path / "m")
        assert err.value.field == "status"
    finally:
        first.kill()
        first.wait(10)


@pytest.mark.timeout(240)
def test_a_killed_campaigns_lock_is_taken_over_and_merge_needs_to_be_asked(long_protocol, tmp_path, caplog):
    folder = tmp_path / "c"
    first = _start(long_protocol, folder)
    _wait_for_presses(folder, 3)
    os.kill(first.pid, signal.SIGKILL)
    first.wait(10)
    held, holder = lock_state(folder)
    assert not held and holder.pid == first.pid
    assert describe(folder)["status"].startswith(f"crashed (last run by PID {first.pid}")

    done = len(read_presses(folder))
    other = tmp_path / "other"
    shutil.copytree(folder, other)
    with pytest.raises(DataError, match="not complete"):
        merge([folder, other], tmp_path / "m1")
    out = merge([folder, other], tmp_path / "m2", allow_incomplete=True)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["allow_incomplete"] is True and manifest["counts"]["completed"] == 2 * done
    assert [s["status"][:7] for s in read_metadata(out)["merged_from"]] == ["crashed", "crashed"]

    with caplog.at_level("WARNING", logger="neatskin.datasets.lock"):
        result = resume_campaign(folder, progress=False, report=False)
    assert f"taking over a stale lock of {folder}: PID {first.pid}" in caplog.text
    assert result.completed == 120 and result.written_now == 120 - done
    assert lock_state(folder) == (False, None) and describe(folder)["status"] == "complete"


def test_the_lock_is_exclusive_between_processes_and_reentrant_within_one(tmp_path):
    with CampaignLock(tmp_path):
        with CampaignLock(tmp_path):  # resume holds it while run_campaign takes it again
            assert lock_state(tmp_path)[0] is True
        assert lock_state(tmp_path)[0] is True
        probe = subprocess.run(
            [
                sys.executable,
                "-c",
                "import sys; from neatskin.datasets.lock import CampaignLock; CampaignLock(sys.argv[1]).acquire()",
                str(tmp_path),
            ],
            capture_output=True,
            text=True,
        )
        assert probe.returncode == 1 and f"in use by PID {os.getpid()}" in probe.stderr
    assert lock_state(tmp_path) == (False, None)

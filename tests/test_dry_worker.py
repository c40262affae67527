"""The dry run's skin worker (neatskin.sim.skinworker): a campaign whose pair estimates come from the worker
process records exactly the inline path's rows; every press pressed reaches the writer before a stop; a worker
that fails, dies or hangs ends the campaign with one error naming the press; a SIGKILL of the campaign leaves
no worker behind and resume equals an uninterrupted run; Ctrl-C stops cleanly."""

import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import PROTOCOLS, WORKER_PRESSES, shared_folder, write_worker_protocol

import neatskin.rig.control as control
import neatskin.rig.dryrig as dryrig
import neatskin.sim.dryscene as dryscene
import neatskin.sim.skinworker as skinworker
from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses
from neatskin.errors import ConfigError, HardwareError
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign
from neatskin.sim.skinworker import EstimateJob, SkinWorker

PRESSES = WORKER_PRESSES
COMPARED = ["press_id", "flags", "fsr_onset_s", "fsr_offset_s", "fsr_peak_n"]
FAIL_AT = 40


# Session-scoped (this module's fixtures still): made once per worker. Module-scoped, they were made again each
# time the suite's long-first order came back to this module after another one (12 s for the inline run).
@pytest.fixture(scope="session")
def worker_protocol(tmp_path_factory):
    """512 presses (8 positions x 64 repeats), features only, the paper-like scene: placement error, depth
    jitter, drift and the dents of earlier presses, so every per-press condition reaches the worker."""
    path = write_worker_protocol(tmp_path_factory.mktemp("protocols"), paper_like=True)
    assert build_plan(load_protocol(path)).n_presses == PRESSES
    return path


@pytest.fixture(scope="session")
def inline_rows(worker_protocol, tmp_path_factory):
    """The inline path's rows (no worker), run once per session (conftest.shared_folder): the suite's long-first
    order spreads this module's long tests over both workers, and each ran the 512 presses again."""

    def make(root: Path) -> None:
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv(dryrig.SKIN_WORKER_ENV, "off")
            run_campaign(load_protocol(worker_protocol), root / "run", progress=False, report=False)

    return _rows(shared_folder(tmp_path_factory, "dry-worker-inline", make) / "run")


@pytest.fixture
def worker_on(monkeypatch):
    monkeypatch.setenv(dryrig.SKIN_WORKER_ENV, "on")


def _rows(folder: Path) -> pd.DataFrame:
    df = read_presses(folder)
    df.attrs = {}
    r = df.filter(regex=r"^d?R_ohm_").astype(float)
    return pd.concat([df[COMPARED].assign(flags=df["flags"].map(list)), r], axis=1)


def _worker_pids(caplog) -> list[int]:
    return [int(m) for r in caplog.records for m in re.findall(r"skin worker started, pid (\d+)", r.getMessage())]


def _gone(pid: int, within_s: float = 10.0) -> bool:
    """The process ended (gone, or a zombie nobody reaped) within the time given."""
    deadline = time.monotonic() + within_s
    while True:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state == "Z":
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)


def test_the_worker_records_the_inline_rows_bit_for_bit(worker_protocol, inline_rows, tmp_path, worker_on, caplog):
    caplog.set_level(logging.DEBUG, logger="neatskin.sim.skinworker")
    result = run_campaign(load_protocol(worker_protocol), tmp_path / "run", progress=False, report=False)
    assert result.completed == result.written_now == PRESSES
    (pid,) = _worker_pids(caplog)
    assert _gone(pid, 0.0)  # closed with the rig
    rows = _rows(tmp_path / "run")
    assert rows["R_ohm_1_2"].notna().all() and len(rows) == PRESSES
    pd.testing.assert_frame_equal(rows, inline_rows, check_exact=True)


def test_a_stop_writes_every_press_pressed_first(worker_protocol, inline_rows, tmp_path, worker_on, monkeypatch):
    after_press = control.Checkpoint.after_press

    def stop_at_100(self, press_id, flags):
        return self._stop("test") if press_id == 100 else after_press(self, press_id, flags)

    monkeypatch.setattr(control.Checkpoint, "after_press", stop_at_100)
    folder = tmp_path / "run"
    result = run_campaign(load_protocol(worker_protocol), folder, progress=False, report=False)
    assert result.interrupted and result.completed == result.written_now == 101
    pd.testing.assert_frame_equal(_rows(folder), inline_rows.iloc[:101], check_exact=True)
    assert json.loads((folder / "manifest.json").read_text())["status"] == "interrupted"


def failing_estimator(dry, sweep):
    """The real estimator, raising on press FAIL_AT (built in the worker: pickled by name)."""
    estimate = dryscene.skin_estimator(dry, sweep)  # in the worker: the module as shipped

    def failing(job):
        if job.press_id == FAIL_AT:
            raise ValueError("the skin model broke")
        return estimate(job)

    return failing


def dying_estimator(dry, sweep):
    """The real estimator; the worker process exits with code 3 on press FAIL_AT."""
    estimate = dryscene.skin_estimator(dry, sweep)

    def dying(job):
        if job.press_id == FAIL_AT:
            os._exit(3)
        return estimate(job)

    return dying


@pytest.mark.parametrize(
    "factory, message",
    [
        (failing_estimator, f"skin worker failed on press {FAIL_AT}: ValueError: the skin model broke"),
        (dying_estimator, f"skin worker \\(pid \\d+\\) ended \\(exit code 3\\) before press {FAIL_AT}'s estimates"),
    ],
)
def test_a_worker_failure_is_one_error_naming_the_press(
    worker_protocol, inline_rows, tmp_path, worker_on, monkeypatch, factory, message
):
    monkeypatch.setattr(dryrig, "skin_estimator", factory)
    folder = tmp_path / "run"
    with pytest.raises(HardwareError, match=message):
        run_campaign(load_protocol(worker_protocol), folder, progress=False, report=False)
    pd.testing.assert_frame_equal(_rows(folder), inline_rows.iloc[:FAIL_AT], check_exact=True)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == FAIL_AT
    assert f"press {FAIL_AT}" in manifest["stopped_by"]


def sleepy_estimator():
    def sleepy(job):
        time.sleep(60)

    return sleepy


def test_every_wait_on_the_worker_has_a_deadline():
    worker = SkinWorker(sleepy_estimator, press_timeout_s=0.5).start()
    try:
        ticket = worker.submit(EstimateJob(7, 1, ()))
        started = time.monotonic()
        with pytest.raises(HardwareError, match="gave no estimates for press 7 within 0 s"):
            worker.result(ticket, 7)
        assert time.monotonic() - started < 30  # not the 60 s the job sleeps (start-up has its own deadline)
        with pytest.raises(HardwareError, match="press 7"):  # once broken, at once
            worker.submit(EstimateJob(8, 1, ()))
        pid = worker.pid
    finally:
        worker.close()  # ends the sleeping worker (terminate after CLOSE_TIMEOUT_S)
    assert pid is not None and _gone(pid, 0.0)


def test_fork_is_refused():
    with pytest.raises(ValueError, match="fork"):
        SkinWorker(sleepy_estimator, context="fork")


def test_who_gets_a_worker(worker_protocol, monkeypatch):
    monkeypatch.delenv(dryrig.SKIN_WORKER_ENV, raising=False)
    features = load_protocol(worker_protocol)
    smoke = load_protocol(PROTOCOLS / "smoke.toml")  # the waveforms scene stays inline
    two_cores = len(os.sched_getaffinity(0)) >= 2
    assert dryrig.use_skin_worker(features, PRESSES) is two_cores
    assert dryrig.use_skin_worker(features, PRESSES - 1) is False
    assert dryrig.use_skin_worker(smoke, 10_000) is False
    assert dryrig.use_skin_worker(smoke, 10_000, skin_worker=True) is False
    assert dryrig.use_skin_worker(features, 12, skin_worker=True) is True
    monkeypatch.setenv(dryrig.SKIN_WORKER_ENV, "off")
    assert dryrig.use_skin_worker(features, PRESSES) is False
    monkeypatch.setenv(dryrig.SKIN_WORKER_ENV, "on")
    assert dryrig.use_skin_worker(features, 12) is True
    assert dryrig.use_skin_worker(features, 12, skin_worker=False) is False
    monkeypatch.setenv(dryrig.SKIN_WORKER_ENV, "maybe")
    with pytest.raises(ConfigError, match="NEATSKIN_SKIN_WORKER"):
        dryrig.use_skin_worker(features, PRESSES)


def _start_campaign(protocol: Path, folder: Path) -> subprocess.Popen:
    env = dict(os.environ, **{dryrig.SKIN_WORKER_ENV: "on"})
    argv = ["campaign", "run", str(protocol), "--dry-run", "--out", str(folder), "--no-report", "--quiet"]
    return subprocess.Popen(
        [sys.executable, "-m", "neatskin", *argv],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a shell gives a job (Ctrl-C reaches the group)
    )


def _children_once_pressing(proc: subprocess.Popen, folder: Path) -> set[int]:
    """Wait until the campaign has a part on disk; its child processes (the skin worker among them)."""
    deadline = time.monotonic() + 120
    while not (folder.is_dir() and press_parts(folder)) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None and press_parts(folder), proc.communicate()[1] if proc.poll() is not None else "timeout"
    tasks = Path(f"/proc/{proc.pid}/task")
    return {int(c) for task in tasks.iterdir() for c in (task / "children").read_text().split()}


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_sigkill_of_the_campaign_leaves_no_worker_and_resume_equals_inline(
    worker_protocol, inline_rows, tmp_path, worker_on
):
    folder = tmp_path / "campaign"
    proc = _start_campaign(worker_protocol, folder)
    try:
        children = _children_once_pressing(proc, folder)
        assert children
        for pid in children:  # the worker ignores Ctrl-C (SIGINT), SIGTERM and SIGHUP from its start
            status = Path(f"/proc/{pid}/status").read_text()
            ignored = int(re.findall(r"SigIgn:\s+([0-9a-f]+)", status)[0], 16)
            for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                assert ignored & (1 << (signum - 1)), (pid, signum)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    assert all(_gone(pid) for pid in children)  # EOF on its pipe: the worker ends by itself
    assert json.loads((folder / "manifest.json").read_text())["status"] == "running"
    result = resume_campaign(folder, progress=False, report=False)
    assert result.completed == PRESSES
    pd.testing.assert_frame_equal(_rows(folder), inline_rows, check_exact=True)


# SIGINT: what a terminal sends on Ctrl-C; SIGTERM: systemctl stop (every process of the unit); SIGHUP: a lost
# terminal (its foreground group): every process of the job gets it
@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_ctrl_c_to_the_group_stops_cleanly_and_resume_equals_inline(
    worker_protocol, inline_rows, tmp_path, worker_on, signum
):
    folder = tmp_path / "campaign"
    proc = _start_campaign(worker_protocol, folder)
    try:
        children = _children_once_pressing(proc, folder)
        os.killpg(proc.pid, signum)  # every process of the job
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert all(_gone(pid) for pid in children)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted"
    done = manifest["counts"]["completed"]
    assert 0 < done < PRESSES
    pd.testing.assert_frame_equal(_rows(folder), inline_rows.iloc[:done], check_exact=True)
    resume_campaign(folder, progress=False, report=False)
    pd.testing.assert_frame_equal(_rows(folder), inline_rows, check_exact=True)


def echo_estimator():
    def echo(job):
        return ("estimates of", job.press_id, os.getpid())

    return echo


def _prestarted_pid() -> int:
    (entry,) = skinworker._PRESTARTED
    return entry[1].pid


def test_a_prestarted_worker_is_adopted_by_the_next_start():
    """The CLI launches the worker's process before the protocol's plan exists (its start-up overlaps the main
    process's); the next SkinWorker.start adopts that process and sends it the factory."""
    skinworker.prestart(preload=("neatskin.sim.dryscene",))
    pid = _prestarted_pid()
    worker = SkinWorker(echo_estimator).start()
    try:
        assert worker.pid == pid and not skinworker._PRESTARTED
        ticket = worker.submit(EstimateJob(3, 1, ()))
        assert worker.result(ticket, 3) == ("estimates of", 3, pid)  # computed in the prestarted process
    finally:
        worker.close()
    assert _gone(pid, 0.0)


def test_a_prestarted_worker_a_campaign_does_not_use_is_ended():
    skinworker.prestart()
    pid = _prestarted_pid()
    protocol = load_protocol(PROTOCOLS / "smoke.toml")  # the waveforms scene computes inline
    rig = dryrig.build_dry_rig(protocol, build_plan(protocol))
    try:
        assert not skinworker._PRESTARTED and _gone(pid)
    finally:
        for close in reversed(rig.closers):
            close()

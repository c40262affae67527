"""The main job's memory seam: when a dry run's baseline report starts, the campaign has left no process (the skin
worker) and no thread (the physical limit, the G-code driver) behind, and the report's fit worker has ended when
it returns (benchmarks/bench_memory.py measures what this saves; no test asserts a size)."""

import multiprocessing
import os
import threading
from pathlib import Path

import pytest
from conftest import WORKER_PRESSES, write_worker_protocol

import neatskin.baselines.report as report
import neatskin.rig.dryrig as dryrig
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign

PRESSES = WORKER_PRESSES  # the smallest campaign that gets a skin worker, and a report in processes (above SMALL_ROWS)


def _child_pids() -> list[int]:
    """This process's live children (any kind, not only multiprocessing's), from /proc; but multiprocessing's
    resource tracker, one per process for the life of the process once anything was spawned."""
    me, out = os.getpid(), []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) != me or fields[0] == "Z":
            continue
        if b"resource_tracker" not in Path(f"/proc/{entry}/cmdline").read_bytes():
            out.append(int(entry))
    return out


@pytest.fixture
def worker_protocol(tmp_path):
    path = write_worker_protocol(tmp_path / "protocols", paper_like=False)
    assert build_plan(load_protocol(path)).n_presses == PRESSES
    return path


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_the_report_starts_with_no_campaign_process_or_thread_left_and_leaves_none(
    worker_protocol, tmp_path, monkeypatch
):
    monkeypatch.setenv(dryrig.SKIN_WORKER_ENV, "on")
    threads_before = {t.ident for t in threading.enumerate()}
    others = set(_child_pids())  # an earlier test's pool in this process (e.g. loky's idle workers)
    others_mp = set(multiprocessing.active_children())
    real = report.run_baselines
    seen = {}

    def run_baselines(folder, **kwargs):
        seen["children"] = set(_child_pids()) - others
        seen["mp_children"] = set(multiprocessing.active_children()) - others_mp
        # tqdm's monitor is one thread per process, shared by every progress bar, sleeping: not the campaign's
        seen["threads"] = [
            t.name for t in threading.enumerate() if t.ident not in threads_before and t.name != "tqdm_monitor"
        ]
        # the report itself, smaller: two models, two repeats, in processes as the main job makes it
        made = real(folder, models=["ridge", "extra_trees"], n_repeats=2, **kwargs)
        seen["children_after"] = set(_child_pids()) - others
        return made

    monkeypatch.setattr(report, "run_baselines", run_baselines)
    result = run_campaign(load_protocol(worker_protocol), tmp_path / "run", progress=False, report=True)
    assert result.completed == PRESSES and result.report_summary
    assert seen["children"] == set() and seen["mp_children"] == set()  # the skin worker ended with the rig
    assert seen["threads"] == []  # the physical-limit thread, the driver's reader: all joined
    assert seen["children_after"] == set()  # the report's fit worker ended with its tasks
    assert (tmp_path / "run" / "report.md").is_file()

"""Shared pieces of the fault-injection suite (tests/test_faults_*.py): a smoke campaign, a way to run the CLI
in a child process that kills itself at a named stage, and the comparison with an uninterrupted run."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest
from conftest import PROTOCOLS, REPO

SMOKE = PROTOCOLS / "smoke.toml"
WALL_CLOCK = ["started_at", "finished_at"]

# Each stage replaces one function of the toolkit, in the child only, by one that SIGKILLs the process there.
_CHILD = r"""
import os, signal, sys

def die(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)

stage, argv = sys.argv[1], sys.argv[2:]
import neatskin.datasets.consolidate as consolidate
import neatskin.datasets.manifest as manifest
import neatskin.datasets.writer as writer
import neatskin.rig.folder as folder
import neatskin.rig.runner as runner

if stage == "folder-creation":  # inputs/ and manifest.json built under the staging name, not yet renamed
    os.rename = die
elif stage == "rig-open":  # the folder exists, the rig is being opened
    runner._open_rig = die
elif stage == "presses":  # five presses durable, the sixth not started
    write_press, count = writer.CampaignWriter.write_press, [0]
    def write_then_die(self, *args, **kwargs):
        path = write_press(self, *args, **kwargs)
        count[0] += 1
        if count[0] == 5:
            die()
        return path
    writer.CampaignWriter.write_press = write_then_die
elif stage == "finalize":  # presses.parquet written, its copy and the parts' deletion not yet
    consolidate.keep_copy = die
elif stage == "physical-limit":  # consolidated, the physical limit not yet written
    import neatskin.rig.dryrig as dryrig  # the dry rig derives its physical limit (Rig.derived_files)
    dryrig.write_physical_limit = die
elif stage == "complete":  # every file written, the manifest not yet `complete`
    update = manifest.update_manifest
    def update_or_die(*args, **kwargs):
        if kwargs.get("status") == "complete":
            die()
        return update(*args, **kwargs)
    manifest.update_manifest = runner.update_manifest = update_or_die  # the runner imported it by name
elif stage == "report":  # the manifest says complete, the baseline report is being made
    import neatskin.baselines.report as report
    report.run_baselines = die
elif stage != "none":
    raise SystemExit(f"unknown stage {stage}")

from neatskin.cli import main
sys.exit(main(argv))
"""


def run_cli_child(stage: str, *argv: str, timeout_s: float = 120, **popen) -> subprocess.CompletedProcess:
    """`neatskin ARGV` in a child process that SIGKILLs itself at `stage` ("none": no kill)."""
    return subprocess.run(
        [sys.executable, "-c", _CHILD, stage, *argv],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        **popen,
    )


def rows(folder: Path) -> pd.DataFrame:
    return pd.read_parquet(folder / "presses.parquet").drop(columns=WALL_CLOCK).sort_values("press_id")


def waveforms(folder: Path) -> pd.DataFrame:
    from neatskin.datasets.reader import read_waveforms

    return read_waveforms(folder)


def write_reference(folder: Path) -> None:
    """The smoke campaign, uninterrupted (no report), into `folder` (conftest's smoke_reference)."""
    done = run_cli_child("none", "campaign", "run", str(SMOKE), "--dry-run", "--out", str(folder), "--no-report")
    assert done.returncode == 0, done.stderr


@contextlib.contextmanager
def small_disk(where: Path, size: str) -> Iterator[Path]:
    """A tmpfs of `size` mounted at `where` (a real full disk and a real read-only file system); skips the
    test where mounting is not allowed (not root)."""
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def remount(where: Path, options: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{options}", str(where)], check=True, capture_output=True)

"""Crash safety: a dry-run campaign killed with SIGKILL at random points, resumed, equals an uninterrupted run."""

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import PROTOCOLS, shared_folder

from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

WALL_CLOCK = ["started_at", "finished_at"]


# this module's, made once per worker (module scope remade it whenever the suite's order came back to it)
@pytest.fixture(scope="session")
def kill_protocol(tmp_path_factory):
    """The smoke protocol with more presses (features only), so a kill lands mid-campaign."""
    root = tmp_path_factory.mktemp("protocols")
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("repeats = 2", "repeats = 20").replace("waveforms = true", "waveforms = false")
    text = text.replace('signal = "waveforms"', 'signal = "features"')
    path = root / "kill.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="session")
def reference(kill_protocol, tmp_path_factory):
    """The uninterrupted run's rows, run once per session (conftest.shared_folder)."""

    def make(root: Path) -> None:
        run_campaign(load_protocol(kill_protocol), root / "run", dry_run=True, progress=False, report=False)

    return _rows(shared_folder(tmp_path_factory, "kill-reference", make) / "run")


def _rows(folder: Path) -> pd.DataFrame:
    return pd.read_parquet(folder / "presses.parquet").drop(columns=WALL_CLOCK)


@pytest.mark.timeout(240)
@pytest.mark.parametrize("run", range(3))
def test_sigkill_then_resume_equals_uninterrupted(kill_protocol, reference, tmp_path, run):
    folder = tmp_path / "campaign"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "neatskin",
            "campaign",
            "run",
            str(kill_protocol),
            "--dry-run",
            "--out",
            str(folder),
            "--no-report",
            "--quiet",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    # wait until a random number of presses is durable (the dry run is fast: a timer could outlast it),
    # then kill at a random moment within the next press
    rng = random.Random(run)
    target = rng.randint(5, 60)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list((folder / "presses").glob("part-*.parquet"))) < target:
        time.sleep(0.005)
    time.sleep(rng.uniform(0.0, 0.02))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    done_before = len(list((folder / "presses").glob("part-*.parquet")))
    assert 0 < done_before < len(reference), "the kill should land mid-campaign"

    result = resume_campaign(folder, progress=False, report=False)
    assert result.completed == len(reference) and result.written_now == len(reference) - done_before
    rows = _rows(folder)
    assert rows.press_id.is_unique and len(rows) == len(reference)
    pd.testing.assert_frame_equal(
        rows.sort_values("press_id").reset_index(drop=True),
        reference.sort_values("press_id").reset_index(drop=True),
        check_exact=True,
    )


@pytest.mark.timeout(240)
@pytest.mark.parametrize("preset", ["realistic"])  # extreme rates: tests/test_marlin_faults.py, on shorter programs
def test_a_noisy_serial_line_changes_nothing_recorded(kill_protocol, reference, tmp_path, preset):
    """Corrupted bytes, lost oks, dropped lines, duplicated replies and busy storms on the pty: every G-code
    line still runs exactly once, so the dataset equals the one recorded over a clean line."""
    from neatskin.marlin.wirelog import read_wire_log
    from neatskin.sim.faults import FaultConfig

    folder = tmp_path / "run"
    run_campaign(
        load_protocol(kill_protocol),
        folder,
        dry_run=True,
        progress=False,
        report=False,
        printer_faults=FaultConfig.parse(preset),
    )
    received = b"".join(data for direction, data in read_wire_log(folder / "wire.log") if direction == "<")
    assert b"Resend:" in received or b"rs " in received  # the faults did happen
    pd.testing.assert_frame_equal(
        _rows(folder).sort_values("press_id").reset_index(drop=True),
        reference.sort_values("press_id").reset_index(drop=True),
        check_exact=True,
    )

"""SIGKILL at random instants while a real process writes presses (fsync on) and finalizes; resume after
each kill; the result has every press exactly once and equals an uninterrupted write."""

import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.datasets.reader import read_presses, read_waveforms
from neatskin.datasets.writer import CampaignWriter
from neatskin.skin.synthetic import synthetic_rows

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

N_POSITIONS, REPEATS = 40, 4  # 160 presses
META = {"seed": 11, "protocol": {"name": "kill"}}

WORKER = r"""
import sys, numpy as np
from neatskin.layout import load_layout
from neatskin.datasets.writer import CampaignWriter
from neatskin.skin.synthetic import synthetic_rows

layout = load_layout(sys.argv[2])
rows = synthetic_rows(layout, %d, %d, seed=11)
writer = CampaignWriter(sys.argv[1], layout.pairs, {"seed": 11, "protocol": {"name": "kill"}}, fsync=True)
done = writer.completed_press_ids()
print("ready", len(done), flush=True)
for row in rows:
    if row["press_id"] not in done:
        writer.write_press(row, {"voltage_v": np.full(200, float(row["press_id"]))})
        print("wrote", row["press_id"], flush=True)
print("finalizing", flush=True)
writer.finalize()
print("finished", flush=True)
""" % (N_POSITIONS, REPEATS)  # noqa: UP031 (the template holds braces)


def run_worker(folder, kill_after_lines=None, then_s=0.0, until_finalizing=False):
    """Run the worker; SIGKILL it `then_s` seconds after it has printed `kill_after_lines` more lines (one per
    durable press, then 'finalizing') or, with until_finalizing, once it starts finalizing; so kills land
    mid-campaign and, with then_s, inside a write or inside finalize.
    Returns (presses it reported durable, whether it finished)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", WORKER, str(folder), str(PROTOCOLS / "skins" / "paper.toml")],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().startswith("ready")
    seen = []
    if kill_after_lines is not None:
        for _ in range(kill_after_lines):
            line = proc.stdout.readline()
            seen.append(line)
            if not line or (until_finalizing and line.startswith("finalizing")):
                break
        time.sleep(then_s)
        proc.send_signal(signal.SIGKILL)
    out, _ = proc.communicate(timeout=120)
    lines = "".join(seen).splitlines() + out.splitlines()
    if kill_after_lines is None:
        assert proc.returncode == 0
    return sum(line.startswith("wrote") for line in lines), "finished" in lines


def test_sigkill_at_random_points_then_resume(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, N_POSITIONS, REPEATS, seed=11)
    with CampaignWriter(tmp_path / "reference", paper_layout.pairs, META, fsync=False) as writer:
        for row in rows:
            writer.write_press(row, {"voltage_v": np.full(200, float(row["press_id"]))})
        writer.finalize()
    reference = read_presses(tmp_path / "reference")

    rng = np.random.default_rng(2026)
    folder = tmp_path / "killed"
    progress, reported = [], []
    plan = [(int(rng.integers(1, 40)), float(rng.uniform(0.0, 0.004))) for _ in range(4)]
    plan.append((len(rows) + 1, float(rng.uniform(0.0, 0.05))))  # the rest of the presses, then into finalize
    for k, (lines, then_s) in enumerate(plan):
        reported.append(run_worker(folder, lines, then_s, until_finalizing=k == len(plan) - 1)[0])
        # after each kill: what is on disk reads cleanly and equals the reference rows of those press ids
        df = read_presses(folder)
        progress.append(len(df))
        pd.testing.assert_frame_equal(df, reference[reference["press_id"].isin(df["press_id"])].reset_index(drop=True))
    # every press a worker reported durable is on disk, plus at most the one it was killed before reporting
    for k, (lines, _) in enumerate(plan[:-1]):
        new = progress[k] - (progress[k - 1] if k else 0)
        assert reported[k] <= new <= reported[k] + 1, (progress, reported)
        assert new >= lines, (progress, reported)
    assert progress[-1] == len(rows), progress
    assert run_worker(folder)[1] is True

    final = read_presses(folder, deduplicate=False)
    assert final["press_id"].tolist() == list(range(len(rows)))
    pd.testing.assert_frame_equal(final, reference)
    assert list((folder / "presses").iterdir()) == []
    assert not [p for p in folder.rglob(".*.tmp")]
    wf = read_waveforms(folder)
    assert len(wf) == 200 * len(rows)
    assert (wf.groupby("press_id")["voltage_v"].first().to_numpy() == np.arange(len(rows))).all()

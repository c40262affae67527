"""Warnings reach the terminal as one line each, in the toolkit's voice, not as Python's file:line: Class: text
with the source line under it."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

from test_baselines_report import small_table, write_dataset

from neatskin.baselines.evaluate import BaselineWarning
from neatskin.cli import format_warning

REPO = Path(__file__).resolve().parent.parent


def test_a_command_that_warns_prints_one_line_per_warning(tmp_path):
    folder = write_dataset(tmp_path / "ds", small_table(8, 3))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "neatskin", "baselines", str(folder), "--models", "ridge,knn", "--repeats", "2"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    warned = [ln for ln in done.stderr.splitlines() if "warning" in ln.lower()]
    assert warned, done.stderr  # 24 presses: the few-test-rows warning
    assert all(ln.startswith("neatskin: warning: ") for ln in warned), warned
    assert "BaselineWarning" not in done.stderr and ".py:" not in done.stderr
    assert "warnings.warn" not in done.stderr and "run_baselines(" not in done.stderr  # no source line under it


def test_format_warning_folds_lines_and_names_a_foreign_warnings_origin():
    ours = format_warning("few rows;\n  record more", BaselineWarning, "/x/neatskin/baselines/report.py", 163)
    assert ours == "neatskin: warning: few rows; record more\n"
    foreign = format_warning("overflow encountered", RuntimeWarning, "/v/site-packages/numpy/core/fromnumeric.py", 3)
    assert foreign == "neatskin: warning (RuntimeWarning in fromnumeric): overflow encountered\n"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the hook formats; it does not change what is shown
        assert format_warning("x", UserWarning, "", 0) == "neatskin: warning: x\n"

"""A real run's printed resume command works as printed; a campaign too small for the report ends without one.

The end of an interrupted real run prints `resume with: neatskin campaign resume <folder>`: that command, exactly,
resumes on the printer port and with the DAQ the manifest records (`rig.printer`, `rig.daq`). A campaign of a few
presses (a test of the rig) is too small for the baseline report's grouped split: it ends with one note, exit 0,
and neither resume nor finish retries the report. The real rig here is the simulated printer on a pty reached
through --port, with the simulated DAQ (the hardware-in-the-loop rig of tests/test_hil.py).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neatskin.cli import main
from neatskin.datasets.manifest import read_manifest, update_manifest
from neatskin.errors import ExitCode
from neatskin.gcode.profile import load_printer_profile
from neatskin.rig.runner import CampaignResult
from neatskin.rig.summarytext import run_summary as _summary
from neatskin.sim.printer import SimulatedPrinter

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"


def small_protocol(tmp_path: Path, count: int, repeats: int) -> Path:
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("count = 6", f"count = {count}").replace("repeats = 2", f"repeats = {repeats}")
    for sub in ("skins/", "wiring/", "printers/"):
        text = text.replace(f'"{sub}', f'"{PROTOCOLS}/{sub}')
    path = tmp_path / "small.toml"
    path.write_text(text)
    return path


@pytest.fixture
def sim_port():
    printer = SimulatedPrinter(load_printer_profile(PROTOCOLS / "printers" / "paper.toml"), advanced_ok=True)
    try:
        yield printer.start_pty()
    finally:
        printer.stop()


def test_the_printed_resume_command_resumes_a_real_run_on_its_recorded_port(tmp_path, sim_port, capsys):
    """3 positions x 2 presses on the real path, Ctrl-C after the first press; the printed command finishes the campaign on the
    recorded port and DAQ, and (6 presses: 4 training presses in a grouped repeat) ends with one note, exit 0."""
    out = tmp_path / "r1"
    argv = ["campaign", "run", str(small_protocol(tmp_path, 3, 2)), "--port", sim_port, "--daq", "simulated"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    child = subprocess.Popen(
        [sys.executable, "-m", "neatskin", *argv, "--out", str(out), "-q"], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        deadline = time.monotonic() + 120
        while not (out / "presses").is_dir() or not any((out / "presses").iterdir()):
            assert time.monotonic() < deadline and child.poll() is None, "no press written"
            time.sleep(0.05)
        child.send_signal(signal.SIGINT)  # Ctrl-C after the first press: the press in flight ends, the probe parks
        printed, _ = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == ExitCode.INTERRUPTED, printed
    written = len(list((out / "presses").iterdir()))
    assert 1 <= written < 6
    match = re.search(r"resume with: (neatskin campaign resume \S+)\)", printed)
    assert match is not None, printed
    assert match.group(1) == f"neatskin campaign resume {out}"
    assert "this wall time" not in printed  # a real printer runs in real time: no speed ratio
    assert re.search(rf"printer time [0-9.]+ s for the {written} press(es)? written now", printed)
    rig = read_manifest(out)["rig"]
    assert (rig["kind"], rig["printer"], rig["daq"]) == ("real", sim_port, "simulated")

    assert main(shlex.split(match.group(1))[1:]) == ExitCode.OK  # exactly as printed: no --port, no --daq
    captured = capsys.readouterr()
    notes = [line for line in captured.out.splitlines() if line.startswith("note: no baseline report")]
    assert notes == [
        "note: no baseline report: 6 presses are too few for its splits (only 4 training presses in a grouped "
        "repeat; record at least 6 presses per fold)"
    ]
    assert "campaign complete: 6/6 presses" in captured.out and f"{6 - written} written now" in captured.out
    manifest = read_manifest(out)
    assert manifest["status"] == "complete" and manifest["counts"]["completed"] == 6
    assert manifest["rig"]["daq"] == "simulated" and "skipped" in manifest["report"]
    assert not (out / "report.md").exists()
    assert main(["dataset", "validate", str(out)]) == 0
    # the report is not retried: resume finds the campaign complete, finish ends with the same note
    assert main(["campaign", "resume", str(out), "-q"]) == ExitCode.DATA
    assert "already complete" in capsys.readouterr().err
    assert main(["campaign", "finish", str(out), "-q"]) == ExitCode.OK
    assert capsys.readouterr().out.count("note: no baseline report") == 1


def test_a_real_campaign_without_a_recorded_port_names_the_option_resume_has(tmp_path, sim_port, capsys):
    out = tmp_path / "r2"
    argv = ["campaign", "run", str(small_protocol(tmp_path, 2, 1)), "--port", sim_port, "--daq", "simulated"]
    assert main([*argv, "--out", str(out), "--limit", "1", "-q", "--no-report"]) == ExitCode.OK  # --limit: 0
    capsys.readouterr()
    manifest = json.loads((out / "manifest.json").read_text())
    rig = {k: v for k, v in manifest["rig"].items() if k != "printer"}
    update_manifest(out, rig=rig)
    parts = sorted(p.name for p in (out / "presses").iterdir())
    assert main(["campaign", "resume", str(out), "-q"]) == ExitCode.CONFIG
    err = capsys.readouterr().err
    assert "[rig.printer]" in err and f"neatskin campaign resume {out} --port /dev/ttyUSB0" in err
    assert "--dry-run" not in err  # resume has no --dry-run
    assert sorted(p.name for p in (out / "presses").iterdir()) == parts  # nothing recorded is lost
    assert main(["campaign", "resume", str(out), "--port", sim_port, "-q", "--no-report"]) == ExitCode.OK
    assert read_manifest(out)["counts"]["completed"] == 2


def test_a_small_dry_campaign_skips_the_report_with_one_note(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["campaign", "run", str(small_protocol(tmp_path, 3, 2)), "--dry-run", "--out", str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("note: no baseline report: 6 presses are too few for its splits") == 1
    assert "x this wall time (the simulated printer runs faster than real time)" in printed
    assert not (out / "report.md").exists()


def test_a_campaign_big_enough_still_gets_its_report(tmp_path, capsys):
    """The negative control: the smoke campaign (6 x 2) has 8 or more training presses per grouped repeat."""
    out = tmp_path / "s"
    assert main(["campaign", "run", str(small_protocol(tmp_path, 6, 2)), "--dry-run", "--out", str(out), "-q"]) == 0
    assert "note: no baseline report" not in capsys.readouterr().out
    assert (out / "report.md").is_file() and "skipped" not in read_manifest(out)["report"]


def test_the_summary_gives_short_printer_times_in_seconds_and_minutes():
    one = CampaignResult(Path("c"), 6, 1, 1, 0, True, 30.0, 6 * 8.0, None, dry_run=False)
    assert "wall 30 s; printer time 8.0 s for the 1 press written now (motion" in _summary(one)
    assert _summary(one).endswith("homing and DAQ recording not included)")  # real: no ratio
    dry = CampaignResult(Path("c"), 12, 12, 12, 0, False, 2.0, 150.0, None)
    assert "printer time 2.5 min for the 12 presses written now" in _summary(dry)
    assert _summary(dry).endswith(", 75x this wall time (the simulated printer runs faster than real time)")
    long = CampaignResult(Path("c"), 2800, 2800, 2800, 0, False, 4000.0, 6.05 * 3600, None, dry_run=False)
    assert "wall 1.11 h; printer time 6.05 h for the 2800 presses written now" in _summary(long)

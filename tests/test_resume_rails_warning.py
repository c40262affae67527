"""`campaign resume` prints `campaign check`'s pressed-rails warning once, on stderr before any motion, as `campaign
run` does, but counting only the presses left (those not on disk: "N of the M left"): from the campaign's own
recorded protocol (its `inputs/` copies), in process for a dry run, from the forecast child (`python -m
neatskin.rig.railcheck FOLDER`) for a real one. A small paper-skin protocol (20 positions x 2 presses) at 0.5 mA puts
one press past the rails (press 18), at 0.7 mA five (presses 4, 5, 18, 22 and 23); at its 0.2 mA none. A resume with
every such press on disk prints nothing, though `campaign check` warns."""

import re
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from test_run_rails_warning import PORT, cli_on_a_sim_printer

from neatskin.datasets.paths import press_parts

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"


def _small_at(tmp_path: Path, amplitude: str) -> Path:
    """The paper protocol cut to 20 positions x 2 presses at `amplitude` A, beside copies of the files it names."""
    root = tmp_path / "protocols"
    root.mkdir(parents=True)
    for sub in ("skins", "wiring", "printers"):
        (root / sub).symlink_to(PROTOCOLS / sub)
    text = (PROTOCOLS / "paper.toml").read_text()
    for old, new in (
        ("count = 100", "count = 20"),
        ("repeats = 28", "repeats = 2"),
        ("amplitude_a = 0.0002 ", f"amplitude_a = {amplitude} "),
    ):
        assert old in text
        text = text.replace(old, new)
    path = root / "small.toml"
    path.write_text(text)
    return path


def _neatskin(*args: str, code: int = 0, cwd: Path | None = None) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [sys.executable, "-m", "neatskin", *args], capture_output=True, text=True, timeout=240, cwd=cwd
    )
    assert done.returncode == code, done.stderr
    return done


def _pressed_line(check_stdout: str) -> str:
    return next(line for line in check_stdout.splitlines() if "electrical, pressed" in line).strip()


def _left_line(check_line: str, amplitude_ma: str, over: int, left: int) -> str:
    """The resume's line: the check's, from "warning: " on, with the presses left counted (its readings figures
    are those of the presses left too: matched, not spelled)."""
    head = check_line.split("warning: ")[0]
    assert head.startswith("electrical, pressed (") and head.endswith("): ")
    share = f"{100 * over / left:.1f}"
    return (
        re.escape(
            f"{head}warning: {over} of the {left} left ({share} %) put some pair past the rails at {amplitude_ma} mA ("
        )
        + r"\d+ of \d+ readings above \d+ ohm; the largest pressed R_eq \d+ ohm = [\d.]+ V\): flagged clipped and "
        + re.escape("recorded as a cut pair's (R = inf)")
    )


def _press_ids(folder: Path) -> list[int]:
    return sorted(pq.read_table(folder / "presses.parquet", columns=["press_id"]).column("press_id").to_pylist())


@pytest.mark.timeout(300)
def test_a_dry_resume_past_the_rails_warns_once_for_the_presses_left_and_loses_none(tmp_path):
    path = _small_at(tmp_path, "0.0007")
    check_line = _pressed_line(_neatskin("campaign", "check", str(path)).stdout)
    assert "warning: 5 of 40 presses (12.5 %) put some pair past the rails at 0.7 mA" in check_line
    run = tmp_path / "run"
    _neatskin("campaign", "run", str(path), "--dry-run", "--limit", "10", "--no-report", "-q", "--out", str(run))
    assert not (run / "presses.parquet").exists()  # 10 of 40 pressed (4 and 5 among them): interrupted, resumable
    resumed = _neatskin("campaign", "resume", str(run), "--no-report")
    lines = resumed.stderr.splitlines()
    rails = [line for line in lines if "electrical" in line]
    assert len(rails) == 1, resumed.stderr
    prefix = f"{run / 'inputs' / 'protocol.toml'}: "
    assert rails[0].startswith(prefix) and re.fullmatch(_left_line(check_line, "0.7", 3, 30), rails[0][len(prefix) :])
    assert "of 40 presses" not in rails[0]  # not the whole protocol's count: presses 18, 22 and 23 are left
    over, readings = map(int, re.search(r"(\d+) of (\d+) readings", rails[0]).groups())
    assert 3 <= over <= readings <= 30 * 28  # the readings of the 30 presses left
    assert lines.index(rails[0]) < next(k for k, line in enumerate(lines) if "paper (dry-run):" in line)  # the bar
    assert "past the rails" not in resumed.stdout and "Traceback" not in resumed.stderr
    assert "campaign complete: 40/40 presses" in resumed.stdout and "(30 written now" in resumed.stdout
    assert _press_ids(run) == list(range(40))  # none lost, none twice


@pytest.mark.timeout(300)
def test_a_dry_resume_whose_presses_past_the_rails_are_on_disk_prints_no_rails_line(tmp_path):
    """The negative control: at 0.5 mA `campaign check` (and the whole protocol's count) warns of press 18; with
    presses 0 to 19 on disk none of the 20 left passes the rails, so the resume says nothing."""
    path = _small_at(tmp_path, "0.0005")
    assert "warning: 1 of 40 presses" in _pressed_line(_neatskin("campaign", "check", str(path)).stdout)
    run = tmp_path / "run"
    _neatskin("campaign", "run", str(path), "--dry-run", "--limit", "20", "--no-report", "-q", "--out", str(run))
    resumed = _neatskin("campaign", "resume", str(run), "--no-report", "-q")
    assert "electrical" not in resumed.stderr + resumed.stdout, resumed.stderr
    assert "campaign complete: 40/40 presses" in resumed.stdout and "(20 written now" in resumed.stdout
    assert _press_ids(run) == list(range(40))


@pytest.mark.timeout(300)
def test_a_dry_resume_at_the_protocols_current_prints_no_rails_line(tmp_path):
    path = _small_at(tmp_path, "0.0002")
    run = tmp_path / "run"
    _neatskin("campaign", "run", str(path), "--dry-run", "--limit", "3", "--no-report", "-q", "--out", str(run))
    resumed = _neatskin("campaign", "resume", str(run), "--no-report", "-q")
    assert "electrical" not in resumed.stderr + resumed.stdout, resumed.stderr
    assert "campaign complete: 40/40 presses" in resumed.stdout
    assert _press_ids(run) == list(range(40))
    again = _neatskin("campaign", "resume", str(run), "--no-report", code=5)  # complete: nothing moves, no line
    assert "already complete" in again.stderr and "electrical" not in again.stderr


@pytest.mark.timeout(300)
def test_a_real_resume_warns_from_the_forecast_child_before_the_rig_opens(tmp_path):
    """A dry campaign resumed on a printer port (a `neatskin sim printer` on a pty, the NI DAQ missing): the line
    comes from the child, read from the folder's recorded protocol and counting the 38 presses left (press 18 among
    them), before the rig's error; the presses stay."""
    path = _small_at(tmp_path, "0.0005")
    check_line = _pressed_line(_neatskin("campaign", "check", str(path)).stdout)
    run = tmp_path / "run"
    _neatskin("campaign", "run", str(path), "--dry-run", "--limit", "2", "--no-report", "-q", "--out", str(run))
    args = ["campaign", "resume", str(run), "--port", PORT, "--no-report", "-q"]
    probe = ("neatskin.skin.model", "neatskin.sim.daq", "neatskin.rig.railcheck")
    out, imported = cli_on_a_sim_printer(args, probe, tmp_path)
    assert imported == []  # the line came from the child
    lines = out.stderr.splitlines()
    prefix = f"{run / 'inputs' / 'protocol.toml'}: "
    rails = [k for k, line in enumerate(lines) if "electrical" in line]
    assert len(rails) == 1, out.stderr
    warning = lines[rails[0]]
    assert warning.startswith(prefix) and re.fullmatch(_left_line(check_line, "0.5", 1, 38), warning[len(prefix) :])
    error = next(k for k, line in enumerate(lines) if "neatskin: error:" in line)
    assert rails[0] < error and "nidaqmx" in out.stderr
    on_disk = [i for part in press_parts(run).values() for i in pq.read_table(part).column("press_id").to_pylist()]
    assert sorted(on_disk) == [0, 1]  # the 2 pressed before stay, and no press was added

"""The CLI: `neatskin sim printer` serves a pty whose path is the first line out; `neatskin printer send` streams to it."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from neatskin.cli import main

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.timeout(60)
def test_sim_printer_then_printer_send(tmp_path, capsys):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "neatskin",
            "sim",
            "printer",
            "--time",
            "virtual",
            "--faults",
            "corrupt=0.05,drop_ok=0.02",
            "--seed",
            "3",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/")
        program = tmp_path / "square.gcode"
        moves = [f"G1 X{x} Y{y} F6000" for x, y in [(10, 10), (60, 10), (60, 60), (10, 60)] * 25]
        program.write_text("; a square, 25 times\nG28\n" + "\n".join(moves) + "\nM400\n")
        log = tmp_path / "wire.log"
        assert (
            main(
                [
                    "printer",
                    "send",
                    "--port",
                    path,
                    "--boot-timeout-s",
                    "0.1",
                    "--no-progress",
                    "--wire-log",
                    str(log),
                    str(program),
                ]
            )
            == 0
        )
        assert capsys.readouterr().out.startswith("sent 102 lines to /dev/pts/")
        assert b"N1 G28*18" in log.read_bytes()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert "stopped after" in err


@pytest.mark.timeout(30)
def test_printer_send_refuses_bad_gcode_before_opening_the_port(tmp_path, capsys):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G28\nfoo bar\n")
    assert main(["printer", "send", "--port", "/dev/nonexistent-port", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.gcode" in err and "line 2" in err and "'foo' is not a G, M or T command" in err


def test_sim_printer_refuses_a_bad_fault_spec(capsys):
    assert main(["sim", "printer", "--faults", "noise=1"]) == 2
    assert "unknown fault 'noise'" in capsys.readouterr().err

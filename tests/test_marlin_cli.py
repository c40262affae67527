"""The CLI: `neatskin sim printer` serves a pty whose path is the first line out; `neatskin printer send` streams to it."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from neatskin.cli import main

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

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
        # 1 mm sides: the printer runs in virtual time, the CLI bounds a lost ok by the motion in real time
        moves = [f"G1 X{x} Y{y} F6000" for x, y in [(10, 10), (11, 10), (11, 11), (10, 11)] * 25]
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
    assert main(["printer", "send", "--port", "/dev/nonexistent-port", str(bad)]) == 3
    err = capsys.readouterr().err
    assert "bad.gcode" in err and "line 2" in err and "'foo' is not a G, M or T command" in err


def test_printer_send_refuses_what_the_firmware_would_not_run_as_written_before_opening_the_port(tmp_path, capsys):
    """Lower case (stock Marlin: unknown command, or a parameter ignored) and a line past what Marlin keeps (a
    numbered one fails its checksum on every resend): every such line named, nothing sent."""
    bad = tmp_path / "bad.gcode"
    bad.write_text("G28\ng1 X10\nG1 X5 y7\nM118 E1 any case text\nG1 " + "X1.000000000 " * 8 + "\n")
    assert main(["printer", "send", "--port", "/dev/nonexistent-port", str(bad)]) == 3
    err = capsys.readouterr().err
    assert "[line 2]" in err and "[line 3]" in err and "[line 5]" in err and "[line 4]" not in err
    assert "upper case ('G1 X5 Y7')" in err and "/dev/nonexistent-port" not in err


def test_sim_printer_refuses_a_bad_fault_spec(capsys):
    assert main(["sim", "printer", "--faults", "noise=1"]) == 3
    assert "unknown fault 'noise'" in capsys.readouterr().err


def _executed_program(sim) -> list[str]:
    return [t for _, t in sim.executed if not t.startswith("M110") and "neatskin-probe" not in t]


@pytest.mark.timeout(120)
def test_ctrl_c_stops_after_the_line_in_flight_lifts_and_from_line_continues_once(tmp_path):
    import os
    import re
    import time

    from neatskin.sim.printer import sim_printer_for_tests

    sim = sim_printer_for_tests(time_mode="scaled", speed=10.0)
    path = sim.start_pty()
    moves = []
    for i in range(60):  # presses: down to Z 9.x (below the 10 mm safe height), up to 12
        moves += [f"G1 X{20 + i % 5} Y{30 + i % 4} Z12 F6000", f"G1 Z{9.5 + (i % 3) / 10:.1f} F1200"]
    program = tmp_path / "presses.gcode"
    program.write_text("; presses\nG28\n" + "\n".join(moves) + "\nM400\n")
    commands = ["G28", *moves, "M400"]  # no G90/G91 of its own: the lift's are told apart
    profile = str(REPO / "protocols" / "printers" / "paper.toml")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    base = [sys.executable, "-m", "neatskin", "printer", "send", "--port", path, "--no-progress"]
    try:
        proc = subprocess.Popen(
            [*base, "--profile", profile, "--boot-timeout-s", "0.2", str(program)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        end = time.monotonic() + 60
        while len(_executed_program(sim)) < 40 and time.monotonic() < end and proc.poll() is None:
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        acked = re.search(r"acknowledged line (\d+) of .*: '([^']*)'", err)
        assert acked, err
        cont = re.search(r"continue with: (.*)", err)
        assert cont, err
        next_line = int(re.search(r"--from-line (\d+)", cont.group(1)).group(1))
        assert next_line == int(acked.group(1)) + 1
        before = _executed_program(sim)
        # stopped after the acknowledged line: the program ran up to it, then the lift (the probe may be down)
        done = before[: before.index("G91")] if "G91" in before else before
        assert done == commands[: len(done)] and done[-1] == acked.group(2)
        # the profile's travel height is its safe height above the surface, 10 + 5.5 mm, above the program's
        # own Z 12: lifted there, relative, back to absolute, then checked with the firmware's M114
        z = float(done[-1].split("Z")[1].split()[0])
        assert before[len(done) :] == ["G91", f"G0 Z{15.5 - z:.3f} F300", "G90", "M400", "M114"], err
        assert "lifted the probe" in err and "travel height 15.5 mm" in err and "reports Z 15.5 mm" in err
        assert sim.probe_position()[2] == pytest.approx(15.5)

        proc = subprocess.run(
            [*base, "--profile", profile, "--boot-timeout-s", "0.2", "--from-line", str(next_line), str(program)],
            capture_output=True,
            text=True,
            env=env,
            timeout=90,
        )
        assert proc.returncode == 0, proc.stderr
        assert done + _executed_program(sim)[len(before) :] == commands  # every line of the file once, in order
    finally:
        sim.stop()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_ctrl_c_at_depth_ends_at_the_programs_travel_height(tmp_path, signum):
    """No profile: the probe held 2 mm into the skin gets SIGINT (or SIGTERM, SIGHUP: the same stop); it ends at
    the program's own travel height (the highest Z it commanded, 15.5), not at a default 5 mm, and the printer's
    M114 says so."""
    import os
    import time

    from neatskin.sim.printer import sim_printer_for_tests

    sim = sim_printer_for_tests(time_mode="scaled", speed=20.0)  # homing 25 s -> 1.25 s; the dwell 40 s -> 2 s
    path = sim.start_pty()
    program = tmp_path / "press.gcode"
    program.write_text(
        "\n".join(["G28", "G90", "G0 Z15.5 F300", "G0 X100 Y100 F6000", "G1 Z5.5 F300", "G1 Z3.5 F120", "G4 S40"])
        + "\nG0 Z15.5 F300\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "neatskin", "printer", "send", "--port", path, "--no-progress"]
            + ["--boot-timeout-s", "0.2", str(program)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        end = time.monotonic() + 45
        while time.monotonic() < end and not (
            [t for _, t in sim.executed[-1:]] == ["G1 Z3.5 F120"] and sim.probe_position()[2] == pytest.approx(3.5)
        ):
            time.sleep(0.02)
        # the dwell (G4 S40, the line in flight) holds the probe at Z 3.5, 2 mm below the surface at 5.5
        assert sim.probe_position()[2] == pytest.approx(3.5)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=40)
        assert proc.returncode == 130, err
        assert sim.probe_position()[2] == pytest.approx(15.5), err
        assert "lifted the probe by 12.000 mm (Z was 3.5 mm, travel height 15.5 mm)" in err
        assert "the printer reports Z 15.5 mm" in err
    finally:
        sim.stop()


def test_travel_height_is_the_programs_own_or_the_profiles():
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.marlin.cli import travel_height_mm

    lines = ["G28", "G90", "G0 Z15.5 F300", "G1 Z3.5 F120", "G91", "G1 Z2", "G90"]
    assert travel_height_mm(lines, None) == 15.5
    assert travel_height_mm(lines[:2], None) == 0.0  # G28 homes to Z 0: nothing higher yet
    assert travel_height_mm(["G90", "G1 X1"], None) is None  # no Z known at all
    paper = load_printer_profile(REPO / "protocols" / "printers" / "paper.toml")  # surface 5.5, safe 10
    assert travel_height_mm(lines, paper) == 15.5
    assert travel_height_mm(["G28", "G0 Z8"], paper) == 15.5  # the profile's travel height is higher
    assert travel_height_mm(["G28", "G0 Z40"], paper) == 40.0


def test_lift_rule():
    from neatskin.marlin.cli import lift_lines

    assert lift_lines(12.0, 10.0, max_z_mm=50.0, feed_mm_s=5.0, absolute=True).lines == ()
    assert lift_lines(0.5, 10.0, max_z_mm=50.0, feed_mm_s=5.0, absolute=True).lines == ("G91", "G0 Z9.500 F300", "G90")
    assert lift_lines(None, 10.0, max_z_mm=None, feed_mm_s=5.0, absolute=False).lines == (
        "G91",
        "G0 Z10.000 F300",
        "G91",
    )
    assert lift_lines(48.0, 60.0, max_z_mm=50.0, feed_mm_s=5.0, absolute=True).lines[1] == "G0 Z2.000 F300"


@pytest.mark.timeout(30)
def test_sim_printer_built_with_no_motion_before_homing(tmp_path):
    """`--no-motion-before-homing`: a move before G28 gets Marlin's refusal; without it the move runs (stock)."""
    import time

    import serial

    def answer(*flags: str) -> bytes:
        proc = subprocess.Popen(
            [sys.executable, "-m", "neatskin", "sim", "printer", "--time", "virtual", *flags],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        try:
            with serial.Serial(proc.stdout.readline().strip(), timeout=0.2) as port:
                port.reset_input_buffer()
                port.write(b"G1 X10\n")
                got, end = b"", time.monotonic() + 10
                while not got.endswith(b"ok\n") and time.monotonic() < end:
                    got += port.read(64)
                return got.split(b"M301 P22.20 I1.08 D114.00\n")[-1]  # the banner, if it came after the flush
        finally:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=10)

    assert answer("--no-motion-before-homing") == b"echo:Home XYZ First\nok\n"
    assert answer() == b"ok\n"


@pytest.mark.timeout(60)
def test_printer_send_with_a_profile_refuses_a_move_outside_the_bed_before_anything_is_sent(tmp_path):
    """`gcode check --profile`'s bounds check, before the port is opened: X 500 on a 220 mm bed and Z -5 below the
    soft limit are each named with the file, the line and the fix, exit 1 as `gcode check`; the simulated
    printer on its pty receives nothing. The same file inside the bed streams (the check is no blanket refusal)."""
    import os

    from neatskin.sim.printer import sim_printer_for_tests

    profile = str(REPO / "protocols" / "printers" / "paper.toml")
    lines = ["G28", "G0 Z10 F300", "G0 X100 Y100 F3000", "G0 X500 Y100 F3000", "G0 Z-5"]
    offbed, inside = tmp_path / "offbed.gcode", tmp_path / "inside.gcode"
    offbed.write_text("\n".join(lines) + "\n")
    inside.write_text("\n".join(lines[:3] + ["G0 X200 Y100 F3000", "G0 Z5"]) + "\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    sim = sim_printer_for_tests(time_mode="virtual")
    path = sim.start_pty()
    wire = tmp_path / "wire.log"
    try:

        def send(program, *extra):
            return subprocess.run(
                [sys.executable, "-m", "neatskin", "printer", "send", "--port", path, "--profile", profile, "-q"]
                + ["--connect-timeout-s", "0.2", "--wire-log", str(wire), *extra, str(program)],
                capture_output=True,
                text=True,
                env=env,
                timeout=50,
            )

        refused = send(offbed)
        assert refused.returncode == 1, refused.stderr
        errors = refused.stderr.splitlines()
        assert len(errors) == 2 and "Traceback" not in refused.stderr
        assert errors[0].startswith(f"neatskin: error: {offbed}: [line 4]: 'G0 X500 Y100 F3000' moves X to 500 mm")
        assert errors[1].startswith(f"neatskin: error: {offbed}: [line 5]: 'G0 Z-5' moves Z to -5 mm")
        assert all("fix: regenerate the program" in e and f"gcode check {offbed} --profile" in e for e in errors)
        assert sim.executed == [] and not wire.exists()  # nothing reached the printer; the port was not opened
        assert send(offbed, "--from-line", "5").returncode == 1  # line 5 alone is still below the bed

        done = send(inside)
        assert done.returncode == 0, done.stderr
        assert [t for _, t in sim.executed if not t.startswith("M110") and "neatskin-probe" not in t] == [
            "G28", "G0 Z10 F300", "G0 X100 Y100 F3000", "G0 X200 Y100 F3000", "G0 Z5",
        ]  # fmt: skip
    finally:
        sim.stop()


@pytest.mark.timeout(60)
def test_printer_send_to_a_peer_acknowledging_lines_never_sent_is_one_error(tmp_path):
    """The audit's peer: a banner, then `ok N<n+1000> P15 B3` to every line (a pty). Before: "sent 5 lines",
    exit 0. Now one error, exit 4, naming the ok and the fix; the wire log shows no line after the handshake."""
    import os

    from neatskin.marlin.wirelog import read_wire_log
    from neatskin.sim.scripted import DialectFirmware, FirmwareOnPty

    program = tmp_path / "p.gcode"
    program.write_text("G28\nG0 Z10 F300\nG0 X100 Y100 F3000\nG0 X120 Y100 F3000\nM400\n")
    peer = FirmwareOnPty(DialectFirmware(mode="ahead"), boot=b"start\necho:Marlin 2.1.2.4\n")
    wire = tmp_path / "wire.log"
    try:
        done = subprocess.run(
            [sys.executable, "-m", "neatskin", "printer", "send", "--port", peer.path, "-q"]
            + ["--connect-timeout-s", "0.2", "--wire-log", str(wire), str(program)],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(REPO)},
            timeout=50,
        )
    finally:
        peer.close()
    assert done.returncode == 4 and "Traceback" not in done.stderr, done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"neatskin: error: the printer and the host are out of step on {peer.path}: ")
    assert "every `ok` named another line (the latest N1000)" in line and "no other program" in line
    sent = b"".join(data for direction, data in read_wire_log(wire) if direction == ">")
    assert set(sent.splitlines()) == {b"N0 M110 N0*125"}  # the handshake and its retries, no line of the file

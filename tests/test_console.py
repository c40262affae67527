"""`neatskin printer console`: the commands on a fake driver (exact lines sent), then the real console over the
simulated printer's pty, driven by scripted keystrokes (pexpect): jog keys, history, calibration points, Ctrl-C."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from neatskin.cli import main
from neatskin.monitor.console import ConsoleSession

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Pos:
    x_mm: float
    y_mm: float
    z_mm: float


class FakeDriver:
    def __init__(self) -> None:
        self.sent: list[str] = []
        self.pos = Pos(0.0, 0.0, 0.0)
        self.interrupt_on: str | None = None
        self.stopped = False

    def send(self, command: str, *, strict: bool = True) -> list[str]:
        self.sent.append(command)
        if command == self.interrupt_on:
            self.interrupt_on = None
            raise KeyboardInterrupt
        return ["echo:fake"] if command.startswith("M503") else []

    def position(self) -> Pos:
        self.sent.append("M114")
        return self.pos

    def endstops(self) -> dict[str, bool]:
        self.sent.append("M119")
        return {"x_min": False, "z_min": True}

    def emergency_stop(self) -> None:
        self.stopped = True


def test_jog_sends_a_relative_move_and_waits():
    d = FakeDriver()
    s = ConsoleSession(d)
    assert s.handle("x+ 10") == ["X0.000 Y0.000 Z0.000"]
    assert d.sent == ["G91", "G0 X10 F3000", "G90", "M400", "M114"]
    d.sent.clear()
    s.handle("step 0.1")
    s.handle("z-")  # down: the position is read first, to check the end against the surface and a clamp
    assert d.sent == ["M114", "G91", "G0 Z-0.1 F300", "G90", "M400", "M114"]
    assert s.handle("y+ 500") == ["jog step must be in (0, 100] mm, got 500.0"]


def test_a_refused_jog_still_returns_to_absolute_mode():
    from neatskin.marlin.errors import CommandRejected

    class Refusing(FakeDriver):
        def send(self, command: str, *, strict: bool = True) -> list[str]:
            super().send(command, strict=strict)
            if command.startswith("G0"):
                raise CommandRejected("'Error: move out of bounds'", last_line=3, last_command=command)
            return []

    d = Refusing()
    with pytest.raises(CommandRejected):
        ConsoleSession(d).handle("z- 50")
    assert d.sent == ["M114", "G91", "G0 Z-50 F300", "G90"]


class Clamping(FakeDriver):
    """Moves the fake probe as Marlin does with soft endstops on: never below Z 0."""

    def send(self, command: str, *, strict: bool = True) -> list[str]:
        super().send(command, strict=strict)
        if command.startswith("G0 Z"):
            dz = float(command.split()[1][1:])
            self.pos = Pos(self.pos.x_mm, self.pos.y_mm, max(0.0, self.pos.z_mm + dz))
        return []


def test_z_down_below_the_calibrated_surface_is_refused_unless_confirmed():
    """Issue 25: `z- 20` from Z 5.5 used to clamp silently at Z 0, 5.5 mm into the skin just calibrated."""
    d = Clamping()
    d.pos = Pos(95.0, 95.0, 5.5)
    s = ConsoleSession(d)
    s.handle("point 0 0")  # the probe touches the surface here: Z 5.5 is the surface from now on
    d.sent.clear()
    assert s.handle("z- 20") == [
        "refused: z- 20 would take the probe to Z -14.500, 20.000 mm below the skin surface at Z 5.500; "
        "type z- 20! to go there anyway"
    ]
    assert d.sent == ["M114"] and d.pos.z_mm == 5.5  # nothing moved
    assert s.handle("z+ 2") == ["X95.000 Y95.000 Z7.500"]
    assert s.handle("z- 2") == ["X95.000 Y95.000 Z5.500"]  # down to the surface itself is allowed
    out = s.handle("z- 20!")  # confirmed: the printer clamps at its soft limit, and the console says so
    assert out == [
        "X95.000 Y95.000 Z0.000",
        "the printer stopped at Z 0.000, not Z -14.500: it clamped the move (a soft limit)",
    ]
    # a profile's surface counts before any point is taken
    d2 = Clamping()
    d2.pos = Pos(0.0, 0.0, 6.0)
    assert (
        ConsoleSession(d2, surface_z_mm=5.5)
        .handle("z- 1")[0]
        .startswith("refused: z- 1 would take the probe to Z 5.000")
    )


def test_ctrl_c_lifts_above_the_known_surface():
    d = FakeDriver()
    d.pos = Pos(10.0, 20.0, 3.5)  # 2 mm into the skin
    s = ConsoleSession(d, lift_mm=5.0, surface_z_mm=5.5)
    s.halt()
    assert d.sent[:4] == ["M400", "M114", "G90", "G0 Z10.500 F300"]  # 5 mm above the surface, not Z 8.5


def test_helpers_and_raw_lines():
    d = FakeDriver()
    s = ConsoleSession(d)
    assert s.handle("m119") == ["x_min:open z_min:TRIGGERED"]
    assert s.handle("M503") == ["echo:fake", "ok"]
    assert d.sent == ["M119", "M503"]
    assert "step MM" in "\n".join(s.handle("help"))
    assert any("M410" in line for line in s.handle("help ctrl-c"))


def test_points_give_the_block_gcode_calibrate_prints(tmp_path, capsys):
    d = FakeDriver()
    s = ConsoleSession(d, calibration_out=tmp_path / "cal.toml")
    assert s.handle("point 0 0")[0] == "point 1: sensor (0, 0) = printer X0.000 Y0.000 Z0.000"
    assert s.handle("undo") == ["dropped point 1: 0,0,0,0,0"]
    d.pos = Pos(95.2, 94.8, 5.6)
    s.handle("point 0 0")
    d.pos = Pos(125.2, 95.3, 5.5)
    s.handle("point 30 0")
    d.pos = Pos(95.0, 124.9, 5.7)
    s.handle("point 0 30")
    block = s.handle("calibration")
    points = ["0,0,95.2,94.8,5.6", "30,0,125.2,95.3,5.5", "0,30,95,124.9,5.7"]
    assert block[-1] == "# from: neatskin gcode calibrate " + " ".join(f"--point {p}" for p in points)
    main(["gcode", "calibrate"] + [a for p in points for a in ("--point", p)])
    assert capsys.readouterr().out.splitlines() == block[:-1]
    assert s.handle("save") == [f"wrote {tmp_path / 'cal.toml'}: paste its [calibration] into the printer profile"]
    assert (tmp_path / "cal.toml").read_text().splitlines() == block


def test_ctrl_c_waits_for_the_move_then_lifts():
    d = FakeDriver()
    d.pos = Pos(10.0, 20.0, 1.5)
    s = ConsoleSession(d, lift_mm=5.0)
    out = s.halt()
    assert d.sent == ["M400", "M114", "G90", "G0 Z6.500 F300", "M400", "M114"]
    assert out[-1] == "halted and lifted 5 mm: X10.000 Y20.000 Z1.500" and not d.stopped


def test_second_ctrl_c_sends_m112():
    d = FakeDriver()
    d.interrupt_on = "M400"
    s = ConsoleSession(d)
    out = s.halt()
    assert d.stopped and s.done and "M112 sent" in out[-1]


# ---- the real console over the simulated printer's pty ---------------------------------------------------------

pexpect = pytest.importorskip("pexpect", reason="pexpect drives the console with keystrokes (pip install pexpect)")


@pytest.fixture
def sim_printer():
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "neatskin", "sim", "printer", "--speed", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    assert proc.stdout is not None
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), path
    yield path
    proc.terminate()
    proc.wait(30)


def test_console_over_the_simulated_printer(sim_printer, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PROMPT_TOOLKIT_NO_CPR": "1", "TERM": "xterm"}
    history = tmp_path / "history"
    child = pexpect.spawn(
        sys.executable,
        ["-m", "neatskin", "printer", "console", "--port", sim_printer, "--history", str(history)]
        + ["--calibration-out", str(tmp_path / "cal.toml")],
        env=env,
        encoding="utf-8",
        timeout=60,
        dimensions=(40, 140),
    )

    def run(keys: str, expect: str, *, line: bool = True) -> None:
        """Type `keys` (and Enter), wait for `expect` in the output, then for the next prompt."""
        child.send(keys + ("\r" if line else ""))
        child.expect_exact(expect)
        child.expect_exact("marlin>")

    try:
        child.expect_exact("marlin>")
        run("home", "X0.000 Y0.000 Z5.000")
        run("x+ 20", "X20.000 Y0.000 Z5.000")
        run("step 5", "jog step 5 mm")
        run("\x1b\x1b[A", "X20.000 Y5.000 Z5.000", line=False)  # Alt+Up: Y+ by the step
        run("\x1b\x1b[5~", "X20.000 Y5.000 Z10.000", line=False)  # Alt+PageUp: Z+
        run("z- 5", "X20.000 Y5.000 Z5.000")
        run("point 0 0", "point 1: sensor (0, 0) = printer X20.000 Y5.000 Z5.000")
        run("x+ 30", "X50.000 Y5.000 Z5.000")
        run("point 30 0", "point 2: sensor (30, 0) = printer X50.000 Y5.000 Z5.000")
        run("save", "wrote")
        run("M114", "X50.000 Y5.000 Z5.000")  # the M114 helper
        run("\x1b[A" * 4, "X80.000 Y5.000 Z5.000")  # history: 4 x Up recalls `x+ 30`, Enter runs it
        # Ctrl-C while the printer is busy with a long move: the move finishes, then the probe lifts 5 mm
        run("G1 X150 F60", "ok")  # 70 mm at 1 mm/s: 70 s, 3.5 s at 20x; acknowledged at once, still moving
        child.send("M400\r")  # waits for the move
        child.expect_exact("\x1b[?2004l")  # prompt_toolkit left the prompt: M400 is in flight
        time.sleep(0.5)  # let it hand the terminal back (cooked mode, so ^C is a SIGINT)
        child.sendintr()
        child.expect_exact("Ctrl-C: letting the move in flight finish (no M410 quickstop), then lifting the probe")
        child.expect_exact("halted and lifted 5 mm: X150.000 Y5.000 Z10.000")
        child.expect_exact("marlin>")
        run("pos", "X150.000 Y5.000 Z10.000")
        child.send("quit\r")
        child.expect(pexpect.EOF)
    finally:
        child.close(force=True)
    assert (tmp_path / "cal.toml").read_text().splitlines()[:5] == [
        "[calibration]",
        "offset_x_mm = 20.000",
        "offset_y_mm = 5.000",
        "rotation_deg = 0.0000",
        "surface_z_mm = 5.000",  # homing leaves Z 5 mm up (Z_POST_CLEARANCE), as Marlin
    ]
    typed = [line[1:] for line in history.read_text().splitlines() if line.startswith("+")]
    assert typed[:3] == ["home", "x+ 20", "step 5"] and typed[-2:] == ["pos", "quit"]


def test_a_typed_move_below_the_surface_is_refused_as_a_jog_is():
    """The z- guard covered jogs only: `G1 Z0` typed over the skin went straight to the printer."""
    d = Clamping()
    d.pos = Pos(95.0, 95.0, 10.0)
    s = ConsoleSession(d, surface_z_mm=5.5)
    assert s.handle("G1 Z0 F300") == [
        "refused: 'G1 Z0 F300' would take the probe to Z 0.000, 5.500 mm below the skin surface at Z 5.500; "
        "type G1 Z0 F300 ! to send it anyway"
    ]
    assert s.handle("g0 x10 z2")[0].startswith("refused: 'g0 x10 z2' would take the probe to Z 2.000")
    assert d.sent == []  # nothing sent, not even M114 (absolute mode)
    assert s.handle("G1 X90 Z5.5") == ["ok"] and s.handle("G1 X80") == ["ok"]  # to the surface, or no Z: sent
    assert s.handle("G1 Z0 F300 !") == ["ok"] and d.sent[-1] == "G1 Z0 F300"  # confirmed: sent without the '!'
    # relative mode typed here: the target is the reported Z plus the move
    s.handle("G91")
    d.pos = Pos(95.0, 95.0, 7.0)
    assert s.handle("G1 Z-1") == ["ok"]  # 7 - 1 = 6, above 5.5
    assert s.handle("G1 Z-2")[0].startswith("refused: 'G1 Z-2' would take the probe to Z 5.000")
    s.handle("G90")
    assert s.handle("G1 Z6") == ["ok"]
    # with no surface known (no profile, no point taken) nothing is refused, as for jogs
    assert ConsoleSession(FakeDriver()).handle("G1 Z0") == ["ok"]
    assert s.handle("!") == []

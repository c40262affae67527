"""The campaign's preamble lifts the probe out of the skin before X and Y home, on the real firmware.

A crash, a SIGKILL or a second Ctrl-C mid-press leaves the probe in the skin (at Z 2 for a 3.5 mm press on a
5.5 mm surface). Marlin's plain G28 raises Z only by Z_CLEARANCE_FOR_HOMING (5 mm stock) while Z is not homed, and
only TO 5 once it is (G28.cpp): X and Y then home with the probe dragging through the skin. The preamble's
`G28 R<surface + safe height>` raises Z by that much, relative to where the firmware believes Z is, homed or not
(bugfix-2.1.x's `seenR`), before homing any axis. These tests send the preamble's own lines to the native build
(../shared/marlin) and read its M114; the simulated printer answers the same.
"""

from __future__ import annotations

import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import serial
from marlin_replay import HOMING_WAIT_S, OK_WAIT_S, replay

from neatskin.gcode.emit import fmt
from neatskin.gcode.parse import parse_line
from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin.replies import frame
from neatskin.marlin.wirelog import read_wire_log
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.sim.printer import SimulatedPrinter
from neatskin.sim.realmarlin import PLAIN, FirmwareRelay, find_marlin_dir

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"
MARLIN = find_marlin_dir(REPO)
NATIVE_PROFILE = PROTOCOLS / "printers" / "marlin-native.toml"
_FRAMED = re.compile(r"^N(\d+) (.*)\*\d+$")
_Z = re.compile(rb"^X:(-?[0-9.]+) Y:(-?[0-9.]+) Z:(-?[0-9.]+) E:", re.MULTILINE)


def smoke_preamble() -> tuple[tuple[str, ...], float]:
    """The smoke campaign's preamble and the raise it should carry: the printer profile's surface + safe height."""
    plan = build_plan(load_protocol(PROTOCOLS / "smoke.toml"))
    profile = load_printer_profile(PROTOCOLS / "printers" / "paper.toml")
    return plan.program.preamble, profile.calibration.surface_z_mm + profile.safe_height_mm


def test_the_preamble_raises_by_the_surface_and_the_safe_height_before_homing():
    preamble, raise_mm = smoke_preamble()
    assert raise_mm == 15.5  # the paper rig: the skin's surface at 5.5, 10 mm over it clears the fittings
    assert preamble == ("G21", "G90", "M211 S1", f"G28 R{fmt(raise_mm)}", "M400")
    homing = [parse_line(line) for line in preamble if line.startswith("G28")]
    assert len(homing) == 1 and homing[0].params == {"R": raise_mm}  # all axes, R the raise


def test_the_dry_run_sends_the_raise_before_any_move(tmp_path):
    """The bytes on the serial line of a dry run (its wire log): the G28 with its R word, framed, before any G0/G1;
    a resume sends the same preamble again (the re-home of a long pause too: rig/pressing)."""
    text = (
        (PROTOCOLS / "smoke.toml").read_text().replace("count = 6", "count = 2").replace("repeats = 2", "repeats = 1")
    )
    for sub in ("skins/", "wiring/", "printers/"):
        text = text.replace(f'"{sub}', f'"{PROTOCOLS}/{sub}')
    protocol = tmp_path / "small.toml"
    protocol.write_text(text)
    out = tmp_path / "run"
    result = run_campaign(load_protocol(protocol), out, dry_run=True, progress=False, report=False, limit=1)
    assert result.completed == 1
    written = b"".join(data for direction, data in read_wire_log(out / "wire.log") if direction == ">")
    assert b"N4 G28 R15.5*122\n" in written  # the line as framed: N4, after M110 N0's G21, G90, M211 S1
    commands = [m.group(2) for raw in written.decode().splitlines() if (m := _FRAMED.match(raw.strip()))]
    first_move = min(i for i, c in enumerate(commands) if c.split()[0] in ("G0", "G1"))
    assert commands[:first_move].count("G28 R15.5") == 1 and "G28" not in commands[:first_move]
    assert commands.index("G28 R15.5") < first_move


def _script(commands: list[str]) -> list[tuple[bytes, float]]:
    return [(b"M110 N0\n", OK_WAIT_S)] + [(frame(c, n), OK_WAIT_S) for n, c in enumerate(commands, start=1)]


def _homing(preamble: tuple[str, ...], axis: str) -> str:
    """The preamble's own G28 line homing only `axis` (so that Z's homing, which ends at 5, does not hide the raise):
    a preamble that lost its raise fails the positions below (a plain G28 X from a homed Z 2 stops at 5)."""
    (line,) = [c for c in preamble if c.split()[0] == "G28"]
    return line.replace("G28", f"G28 {axis}", 1)


def _known_z_script(preamble: tuple[str, ...]) -> tuple[list[str], list[int]]:
    """The printer did not reboot (a resume after a crash of the host): Z homed, the probe left at Z 2. The raise
    alone, then the whole preamble from Z 2 again."""
    x_only = _homing(preamble, "X")
    commands = ["G28", "G1 Z2 F600", "M400", "M114", x_only, "M114", "G1 Z2 F600", "M400", *preamble, "M114"]
    return commands, [4, 6, len(commands)]


def _rebooted_script(preamble: tuple[str, ...]) -> tuple[list[str], list[int]]:
    """The printer rebooted (a reconnect resets it): Z unknown, believed 0 (M114 all zeros), soft endstops on."""
    x_only, y_only = _homing(preamble, "X"), _homing(preamble, "Y")
    commands = ["M211 S1", "M114", x_only, "M114", "G1 Z2 F600", "M400", y_only, "M114"]
    return commands, [2, 4, 8]


def _firmware_replay(commands: list[str]) -> list[tuple[bytes, bytes]]:
    assert MARLIN is not None
    with FirmwareRelay(MARLIN / PLAIN) as relay:
        relay.replies()
        with serial.Serial(relay.path, timeout=0) as port:
            return replay(port.fd, _script(commands), HOMING_WAIT_S)


def _sim_replay(commands: list[str]) -> list[tuple[bytes, bytes]]:
    printer = SimulatedPrinter(load_printer_profile(NATIVE_PROFILE), time_mode="scaled", speed=20.0)
    printer.core.take_output()
    path = printer.start_pty()
    try:
        with serial.Serial(path, timeout=0) as port:
            return replay(port.fd, _script(commands), HOMING_WAIT_S)
    finally:
        printer.stop()


def _positions(transcript: list[tuple[bytes, bytes]], at: list[int]) -> list[tuple[float, float, float]]:
    out = []
    for i in at:
        match = _Z.search(transcript[i][1])  # entry 0 is M110 N0: entry i answers command i
        assert match is not None, transcript[i]
        out.append((float(match.group(1)), float(match.group(2)), float(match.group(3))))
    return out


def _assert_all_accepted(transcript: list[tuple[bytes, bytes]]) -> None:
    for line, got in transcript:
        assert b"ok" in got and b"Error" not in got and b"Unknown command" not in got, (line, got)


def _assert_raises(transcript_known, known_at, transcript_rebooted, rebooted_at) -> None:
    _assert_all_accepted(transcript_known)
    _assert_all_accepted(transcript_rebooted)
    # homed, at Z 2: the raise goes BY 15.5 (to 17.5), where a plain G28 would go only to 5, under the 5.5 surface;
    # after the whole preamble Z is homed and at its post-homing height (5): the program's first move lifts it
    assert _positions(transcript_known, known_at) == [(0.0, 0.0, 2.0), (0.0, 0.0, 17.5), (0.0, 0.0, 5.0)]
    # rebooted: Z believed 0 wherever it is; the raise is relative (15.5 up from the unknown height), and from a
    # believed 2 (a move before homing, M211 S1 clamping no unhomed axis) 17.5
    assert _positions(transcript_rebooted, rebooted_at) == [(0.0, 0.0, 0.0), (0.0, 0.0, 15.5), (0.0, 0.0, 17.5)]


def test_the_simulated_printer_raises_as_the_firmware():
    preamble, _ = smoke_preamble()
    known, known_at = _known_z_script(preamble)
    rebooted, rebooted_at = _rebooted_script(preamble)
    _assert_raises(_sim_replay(known), known_at, _sim_replay(rebooted), rebooted_at)


@pytest.mark.slow
@pytest.mark.timeout(400)
@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
def test_the_real_firmware_raises_the_probe_before_homing_x_and_y():
    """Real time on the native board: two whole G28s (about 30 s each) and four raises of 15.5 mm at 4 mm/s; the
    two firmware processes run side by side."""
    preamble, _ = smoke_preamble()
    known, known_at = _known_z_script(preamble)
    rebooted, rebooted_at = _rebooted_script(preamble)
    with ThreadPoolExecutor(max_workers=2) as pool:
        known_run = pool.submit(_firmware_replay, known)
        rebooted_run = pool.submit(_firmware_replay, rebooted)
        transcript_known, transcript_rebooted = known_run.result(), rebooted_run.result()
    _assert_raises(transcript_known, known_at, transcript_rebooted, rebooted_at)

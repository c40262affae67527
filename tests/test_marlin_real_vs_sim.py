"""The simulated printer answers as the real Marlin does: one command script, replayed against both, byte for byte.

The real firmware is ../shared/marlin's native build (plain and ADVANCED_OK) behind our relay; the
simulator runs a profile with the native build's configuration (protocols/printers/marlin-native.toml),
so the settings report's numbers agree too. Documented exceptions, each normalised below and nowhere else:
- the version, build date and board: `Marlin bugfix-2.1.x` / `echo: Compiled: ...` / `x86_64 Initialized`
  (the HAL's line before `start`), and M115's FIRMWARE_NAME and MACHINE_TYPE line;
- timing: `echo:busy: processing` keep-alives come every 2 s of a long command on either side, at
  times neither controls, so they are left out of both;
- temperatures: the native board's thermistor reads 19.38 C, the simulator's room 25.00 C (M105, M155);
- time: G28 takes 30 s on the native build's simulated board and the simulator's `homing_time_s` (its
  keep-alives are left out, as above; the simulator runs the homing script 10 times faster).
Motion before homing is compared (BEFORE_HOMING): both move from where they believe they are, zeros at boot,
with no `echo:` or `Error:` word, unclamped on axes not homed. So are homing and the soft endstops (HOMING):
G28's Z raises and its position report, M211's report, `M211 S` silent, `M211 S0` clamping nothing.
"""

from __future__ import annotations

import re
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest
import serial
import suite_order
from marlin_replay import (
    BEFORE_HOMING,
    HOMING,
    HOMING_OFFSET,
    HOMING_R,
    HOMING_WAIT_S,
    HOST_TEXT,
    M999_SCRIPT,
    SCRIPT,
    replay,
)

from neatskin.gcode.machine import Home, Machine
from neatskin.gcode.parse import parse_line
from neatskin.gcode.profile import load_printer_profile
from neatskin.sim.printer import SimulatedPrinter
from neatskin.sim.realmarlin import ADVANCED_OK, PLAIN, FirmwareRelay, find_marlin_dir

REPO = Path(__file__).resolve().parent.parent
MARLIN = find_marlin_dir(REPO)
NATIVE_PROFILE = REPO / "protocols" / "printers" / "marlin-native.toml"


_TEMPERATURE = re.compile(rb"([TB]:)\d+\.\d\d(?= /)")


def normalise(data: bytes) -> bytes:
    out = []
    for line in data.splitlines(keepends=True):
        text = line.rstrip(b"\r\n")
        if text in (b"x86_64 Initialized", b"echo:busy: processing"):
            continue
        if text.startswith(b"Marlin "):
            line = b"Marlin <version>\n"
        elif text.startswith(b"echo: Compiled: "):
            line = b"echo: Compiled: <date>\n"
        elif text.startswith(b"FIRMWARE_NAME:"):
            line = b"FIRMWARE_NAME:<name>\n"
        line = _TEMPERATURE.sub(b"\\1<C>", line)
        out.append(line)
    return b"".join(out)


Script = list[tuple[bytes, float]]


def sim_transcript(
    advanced_ok: bool, script: Script = SCRIPT, *, speed: float = 1.0, max_wait_s: float = 10.0
) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    printer = SimulatedPrinter(
        load_printer_profile(NATIVE_PROFILE), advanced_ok=advanced_ok, time_mode="scaled", speed=speed
    )
    banner = printer.core.take_output()  # what it printed at boot (pyserial's open flushes a pty's input)
    path = printer.start_pty()
    try:
        with serial.Serial(path, timeout=0) as port:
            return banner, replay(port.fd, script, max_wait_s)
    finally:
        printer.stop()


def real_transcript(
    build: str, script: Script = SCRIPT, *, max_wait_s: float = 10.0
) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    assert MARLIN is not None
    with FirmwareRelay(MARLIN / build) as relay:
        banner = b"".join(relay.replies())
        with serial.Serial(relay.path, timeout=0) as port:
            return banner, replay(port.fd, script, max_wait_s)


def assert_same_replies(real: list[tuple[bytes, bytes]], sim: list[tuple[bytes, bytes]], script: Script) -> None:
    """Every line of the script answered alike, but for the documented exceptions (normalise)."""
    assert len(sim) == len(real) == len(script)
    for (line, want), (_, got) in zip(real, sim):
        assert normalise(got) == normalise(want), line


# The homing scripts' tests and the scripts they replay to the real firmware's plain build. Each waits 35 to 60 s on
# the firmware's real-time G28s and uses little CPU, so the first of them to run starts the firmware's replays of
# all of them selected in this session at once (tests/suite_order.py starts them one after another on one worker):
# that worker waits about as long as the longest of them, not their sum. Each replay has its own firmware process
# and pty, as when they ran one at a time.
TOGETHER: dict[str, tuple[Script, float]] = {
    "tests/test_marlin_real_vs_sim.py::test_homing_and_soft_endstops_answer_as_the_real_firmware": (
        HOMING,
        HOMING_WAIT_S,
    ),
    "tests/test_marlin_real_vs_sim.py::test_g28_with_an_r_word_answers_as_the_real_firmware": (HOMING_R, HOMING_WAIT_S),
    "tests/test_marlin_real_settings.py::test_m206_applies_at_homing_as_on_the_real_firmware": (
        HOMING_OFFSET,
        HOMING_WAIT_S,
    ),
}
_started: dict[int, Future[tuple[bytes, list[tuple[bytes, bytes]]]]] = {}
_started_lock = threading.Lock()
_replays = ThreadPoolExecutor(max_workers=len(TOGETHER) + 1, thread_name_prefix="real-firmware-replay")


def real_plain_replay(script: Script, max_wait_s: float) -> Future[tuple[bytes, list[tuple[bytes, bytes]]]]:
    """The plain build's transcript of `script`, under way in a thread: a script of TOGETHER's starts with every
    other one of them whose test this session runs (once each), any other script on its own."""
    together = [(test, s, wait_s) for test, (s, wait_s) in TOGETHER.items() if s is script]
    if not together:
        return _replays.submit(real_transcript, PLAIN, script, max_wait_s=max_wait_s)
    with _started_lock:
        if id(script) not in _started:
            selected = suite_order.SELECTED
            for test, (s, wait_s) in TOGETHER.items():
                if s is script or selected is None or test in selected:
                    _started[id(s)] = _replays.submit(real_transcript, PLAIN, s, max_wait_s=wait_s)
        return _started.pop(id(script))


def assert_plain_replays_alike(script: Script, *, speed: float = 1.0, max_wait_s: float = 10.0) -> None:
    """The script replayed to the real firmware's plain build and to the simulator (plain `ok`, `speed` times real
    time), answered alike line by line. The two replays run at once (the firmware's in a thread): each has its own
    pty and process or threads, and both mostly wait on their clocks (G28 in real time on the firmware)."""
    real_run = real_plain_replay(script, max_wait_s)
    _, sim = sim_transcript(advanced_ok=False, script=script, speed=speed, max_wait_s=max_wait_s)
    _, real = real_run.result()
    assert_same_replies(real, sim, script)


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(120)
@pytest.mark.parametrize("build", [PLAIN, ADVANCED_OK])
def test_the_simulator_answers_the_script_as_the_real_firmware(build):
    real_banner, real = real_transcript(build)
    sim_banner, sim = sim_transcript(advanced_ok=build == ADVANCED_OK)
    assert normalise(sim_banner) == normalise(real_banner)
    assert_same_replies(real, sim, SCRIPT)


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(120)
@pytest.mark.parametrize("build", [PLAIN, ADVANCED_OK])
def test_m999_answers_as_the_real_firmware(build):
    """M999 on a running printer: `Resend: 10`, a bare ok and its own ok after N9 (the simulator once said a plain
    `ok`, listing M999 among the silent commands); S1 and a bare S skip the resend, S0 does not."""
    _, real = real_transcript(build, M999_SCRIPT)
    _, sim = sim_transcript(advanced_ok=build == ADVANCED_OK, script=M999_SCRIPT)
    assert_same_replies(real, sim, M999_SCRIPT)
    answers = dict(sim)
    own = b"ok P15 B3\n" if build == ADVANCED_OK else b"ok\n"
    assert answers[b"M999\n"] == b"Resend: 1\nok\n" + own  # the last one, after M110 N0 (the first, after N9: 10)
    assert sim[10] == (b"M999\n", b"Resend: 10\nok\n" + own)


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(120)
def test_moves_before_homing_answer_as_the_real_firmware():
    """Plain `ok`s only: with ADVANCED_OK the planner's free slots (`P`) depend on when the real moves end."""
    assert_plain_replays_alike(BEFORE_HOMING)


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(400)
def test_homing_and_soft_endstops_answer_as_the_real_firmware():
    """Four G28s in real time on the native board (about 70 s); the simulator runs 10 times faster."""
    assert_plain_replays_alike(HOMING, speed=10.0, max_wait_s=HOMING_WAIT_S)


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(200)
def test_g28_with_an_r_word_answers_as_the_real_firmware():
    """G28's R word (about 35 s on the native board): the raise relative to Z even once homed (G28 X R3 at 20 ->
    Z:23.00), none with R0, and before Z's own homing; the simulator once ignored it and answered Z:20.00."""
    assert_plain_replays_alike(HOMING_R, speed=10.0, max_wait_s=HOMING_WAIT_S)


def test_the_g28_r_script_shows_the_relative_raise():
    """The script itself (no firmware needed): what the simulator answers, as the native build did on 2026-11-26."""
    _, sim = sim_transcript(advanced_ok=False, script=HOMING_R, speed=20.0, max_wait_s=HOMING_WAIT_S)
    answers = [normalise(got) for _, got in sim]
    at_23 = b"X:0.00 Y:0.00 Z:23.00 E:0.00 Count X:0 Y:0 Z:9200\nok\n"
    assert answers[4] == answers[5] == answers[6] == answers[7] == at_23  # R3 from 20; R0 raises nothing
    assert answers[8] == answers[9] == b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"


@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
@pytest.mark.timeout(120)
def test_host_text_and_housekeeping_answer_as_the_real_firmware():
    """Comments, blank and lower-case lines, long lines, M155/M113/M31/M500-M503/M108/T0/G2/M410 (HOST_TEXT)."""
    assert_plain_replays_alike(HOST_TEXT)


def test_the_host_text_script_shows_what_marlin_does_with_it():
    """The script itself (no firmware needed): what the simulator answers, as the native build did on 2026-11-26."""
    _, sim = sim_transcript(advanced_ok=False, script=HOST_TEXT)
    answers = [normalise(got) for _, got in sim]
    assert answers[1] == b""  # a comment-only line: nothing, not even an ok
    assert answers[2] == b'echo:Unknown command: ""\nok\n'  # spaces: kept, and unknown
    assert answers[3] == b'echo:Unknown command: "\tM118 E1 tab"\nok\n'
    assert answers[4] == b'echo:Unknown command: "g4 p1"\nok\n'
    assert answers[6] == b"X:1.00 Y:0.00 Z:3.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"  # y2 is no parameter
    assert answers[7] == b"e1 lower flag\r\nok\n"
    assert answers[8] == b"echo:hi \r\nok\n"
    assert answers[9] == b"echo:leading spaces\r\nok\n"
    assert answers[10] == b"echo:" + b"c" * 87 + b"\r\nok\n"  # 95 characters: whole
    assert answers[11] == b"echo:" + b"d" * 87 + b"\r\nok\n"  # 96: the last one cut
    assert answers[13] == b" T:<C> /0.00 B:<C> /0.00 @:0 B@:0\n" * 2 + b"ok\n"  # M155 S1, G4 P2500 (keep-alives aside)
    assert answers[15] == b"echo:M113 S2\nok\n" and answers[17] == b"echo:M113 S1\nok\n"
    assert answers[18] == b"echo:Print time: 0s\nok\n"
    assert answers[21] == b"Warning:EEPROM disabled\nok\n"
    assert answers[23] == b"echo:Hardcoded Default Settings Loaded\nok\n"
    assert answers[24].startswith(b"echo:; Linear Units:\necho:  G21 ; (mm)\n")
    assert answers[25].startswith(b"  G21 ; (mm)\n  M149 C ; Units in Celsius\n")
    assert answers[26] == answers[27] == b"ok\n"  # M108, T0
    assert answers[31] == answers[33] == b"X:2.00 Y:0.00 Z:0.00 E:0.00 Count X:160 Y:0 Z:0\nok\n"  # the arc's end


def test_the_homing_script_shows_the_raises_and_the_reports():
    """The script itself (no firmware needed): what the simulator answers, as the native build did on 2026-11-25."""
    _, sim = sim_transcript(advanced_ok=False, script=HOMING, speed=20.0, max_wait_s=HOMING_WAIT_S)
    answers = [normalise(got) for _, got in sim]
    on = b"  Min:  X0.00 Y0.00 Z0.00   Max:  X200.00 Y200.00 Z200.00\n"
    assert answers[1] == b"  M211 S1 ; ON\n" + on + b"ok\n"
    assert answers[2] == answers[4] == b"ok\n"  # M211 S0 and a bare S (on) say nothing
    assert answers[3] == b"  M211 S0 ; OFF\n" + on + b"ok\n"
    # Z not homed: it rises by 5 from where it is believed (5) before X homes, and the position is reported
    assert answers[7] == b"X:0.00 Y:0.00 Z:10.00 E:0.00 Count X:0 Y:0 Z:4000\nok\n"
    assert answers[10] == b"  M211 S1 ; ON\n  Min:  X0.00 Y0.00 Z-3.00   Max:  X200.00 Y200.00 Z197.00\nok\n"
    assert answers[11] == b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"  # Z homed, then up to 5
    assert answers[16] == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"  # clamped (M211 S1)
    assert answers[20] == b"X:-5.00 Y:0.00 Z:-1.00 E:0.00 Count X:-400 Y:0 Z:-400\nok\n"  # M211 S0: not clamped
    assert answers[24] == answers[16]
    assert answers[27] == b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"  # Z homed at 2: up to 5
    assert answers[29] == b"X:0.00 Y:0.00 Z:20.00 E:0.00 Count X:0 Y:0 Z:8000\nok\n"  # at 20: never down


def test_the_before_homing_script_shows_the_moves():
    """The script itself (no firmware needed): what the simulator answers, as the native build did on 2026-11-25."""
    _, sim = sim_transcript(advanced_ok=False, script=BEFORE_HOMING)
    answers = [got for _, got in sim]
    assert b"echo:" not in b"".join(answers) and b"Error:" not in b"".join(answers)
    assert answers[3] == b"X:10.00 Y:0.00 Z:0.00 E:0.00 Count X:800 Y:0 Z:0\nok\n"  # the queued move, at once
    assert answers[7] == b"X:-5.00 Y:-2.50 Z:5.00 E:0.00 Count X:-400 Y:-200 Z:2000\nok\n"  # below the soft minimum
    assert answers[12] == b"X:-4.00 Y:-1.50 Z:4.00 E:0.00 Count X:-320 Y:-120 Z:1600\nok\n"
    assert answers[13] == b"Reporting endstop status\nx_min: open\ny_min: open\nz_min: open\nok\n"
    assert answers[17] == b"X:3.00 Y:0.00 Z:4.00 E:0.00 Count X:-80 Y:-120 Z:1600\nok\n"  # G92 X0 at -4: native -1


def test_the_script_covers_every_difference_the_issue_lists():
    """The script itself (no firmware needed): each difference has a line that shows it."""
    sent = b"".join(line for line, _ in SCRIPT)
    for needle in (b"M115", b"M114", b"M118 E1", b"M111 S1", b"M118 E1 M112 in text", b"N17 M112*", b"M999"):
        assert needle in sent
    _, sim = sim_transcript(advanced_ok=True)
    answers = dict(sim)
    replies = b"".join(got for _, got in sim)
    assert b"Cap:EMERGENCY_PARSER:0\n" in replies and b"Cap:ADVANCED_OK" not in replies
    assert b"Resend: 11\nok\n" in replies  # a bare ok after every Resend:, ADVANCED_OK or not
    assert answers[SCRIPT[1][0]].endswith(b"ok N1 P15 B3\n")  # an empty planner of 16 reports P15
    assert answers[SCRIPT[2][0]] == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok N2 P15 B3\n"  # before homing
    assert answers[SCRIPT[3][0]] == b"echo:hi\r\nok N3 P15 B3\n"
    assert answers[SCRIPT[6][0]] == b"echo:M112 in text\r\nok N6 P15 B3\n"  # M112 in a text kills nothing
    kill = next(got for line, got in sim if line.startswith(b"N17 M112"))
    assert kill == b"echo:M112 Shutdown\nError:Printer halted. kill() called!\n"
    assert [got for line, got in sim][-3:] == [b"", b"", b""]  # after a kill: nothing, M999 included


_REPORT = re.compile(rb"^X:(-?[0-9.]+) Y:(-?[0-9.]+) Z:(-?[0-9.]+) E:", re.MULTILINE)


def test_the_machine_model_ends_every_g28_where_the_firmware_reports():
    """The host's G-code machine model (gcode.machine, behind the time and bounds estimates and the host's position
    tracker) stepped through the HOMING script from the firmware's boot belief (zeros) is where the simulator
    reports after every G28 and M114: the raise before homing X or Y (relative while Z is not homed, to 5 once
    it is, never down) and Z to 5 once homed. The simulator's answers are the native build's (the test above;
    the raises and reports are also pinned byte for byte in test_the_homing_script_shows_the_raises_and_the_reports).
    M211 is the test's to model (the machine has no soft endstops of its own): its limits on with S1 or a bare
    S, off with S0."""
    profile = load_printer_profile(NATIVE_PROFILE)
    _, sim = sim_transcript(advanced_ok=False, script=HOMING, speed=20.0, max_wait_s=HOMING_WAIT_S)
    on = (tuple(profile.soft_min_mm), tuple(profile.soft_max_mm))
    machine = Machine(profile, start_mm=(0.0, 0.0, 0.0), homing_time_s=profile.homing_time_s, limits_mm=on)
    compared = []
    for line, got in sim:
        command = parse_line(line.decode().strip())
        assert command is not None
        if command.code == "M211" and "S" in command.params:
            s = command.params["S"]
            machine.limits_mm = on if not isinstance(s, float) or s > 0 else None  # type: ignore[assignment]
        event = machine.step(command)
        report = _REPORT.search(got)
        if command.code in ("G28", "M114"):
            assert report is not None, (line, got)
            reported = tuple(float(v) for v in report.groups())
            assert machine.logical_mm == pytest.approx(reported, abs=0.005), line
            compared.append((command.code, reported))
        if command.code == "G28":
            assert isinstance(event, Home) and event.duration_s == pytest.approx(
                profile.homing_time_s * len(event.axes) / 3
            )
    # four G28s, each ending up in Z: 10 (5 above the believed 5), 5 (homed), 5 (from 2), 20 (never down)
    assert [r for code, r in compared if code == "G28"] == [
        (0.0, 0.0, 10.0),
        (0.0, 0.0, 5.0),
        (0.0, 0.0, 5.0),
        (0.0, 0.0, 20.0),
    ]

"""The simulated printer against the real Marlin (../shared/marlin) on what slicers and hosts send around the motion:
the settings commands (M92, M201, M203-M206, M301, M109/M190 S0), a bare M110, M114's 32-bit rounding, cold
extrusion; and what a host meets after M112 (a reset when it reopens the port) and while idle (M155's reports).

The replay scripts are tests/marlin_replay.py's SETTINGS and ROUNDING_AND_EXTRUSION, replayed to both byte for byte
(test_marlin_real_vs_sim's normalise: version, temperatures, keep-alives); the `shows` tests pin what the simulator
answers, as the native build answered on 2026-11-26, so they hold without the firmware too.
"""

from __future__ import annotations

import math
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial
from hypothesis import given
from hypothesis import strategies as st
from marlin_replay import HOMING_OFFSET, HOMING_WAIT_S, ROUNDING_AND_EXTRUSION, SETTINGS
from test_marlin_real_vs_sim import MARLIN, NATIVE_PROFILE, assert_plain_replays_alike, normalise, sim_transcript

from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.sim.printer import SimulatedPrinter
from neatskin.sim.settings import f32, lround32, marlin_float

REPO = Path(__file__).resolve().parent.parent
NO_FIRMWARE = "the real firmware is absent: no shared/marlin beside the repository (or $NEATSKIN_MARLIN_DIR)"


@pytest.mark.skipif(MARLIN is None, reason=NO_FIRMWARE)
@pytest.mark.timeout(180)
def test_settings_commands_answer_as_the_real_firmware():
    assert_plain_replays_alike(SETTINGS)


@pytest.mark.skipif(MARLIN is None, reason=NO_FIRMWARE)
@pytest.mark.timeout(180)
def test_m114_rounding_and_cold_extrusion_answer_as_the_real_firmware():
    assert_plain_replays_alike(ROUNDING_AND_EXTRUSION)


@pytest.mark.skipif(MARLIN is None, reason=NO_FIRMWARE)
@pytest.mark.timeout(300)
def test_m206_applies_at_homing_as_on_the_real_firmware():
    """Two G28s in real time on the native board; the simulator runs 10 times faster."""
    assert_plain_replays_alike(HOMING_OFFSET, speed=10.0, max_wait_s=HOMING_WAIT_S)


def test_the_homing_offset_script_shows_the_offset_belief():
    _, sim = sim_transcript(advanced_ok=False, script=HOMING_OFFSET, speed=20.0, max_wait_s=HOMING_WAIT_S)
    answers = [normalise(got) for _, got in sim]
    homed = b"X:-2.00 Y:0.00 Z:5.00 E:0.00 Count X:-160 Y:0 Z:2000\nok\n"
    assert answers[2] == answers[3] == answers[9] == answers[10] == homed
    assert answers[7] == b"Reporting endstop status\nx_min: open\ny_min: TRIGGERED\nz_min: open\nok\n"


def test_the_settings_script_shows_what_the_native_build_answered():
    _, sim = sim_transcript(advanced_ok=False, script=SETTINGS)
    answers = [normalise(got) for _, got in sim]
    assert answers[1:6] == [b"ok\n"] * 5 and answers[8:10] == [b"ok\n"] * 2  # once unknown commands: plain oks
    assert answers[6] == b"ok\n"
    assert answers[7] == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"  # M206 X0 reports the position
    assert answers[10] == b"Line: 0\nok\n" and answers[11] == b"Line: 1\nok\n" and answers[13] == b"Line: 2\nok\n"
    assert answers[14] == b"ok\n" and answers[15] == b"Line: 7\nok\n" and answers[16] == b"echo:eight\r\nok\n"
    assert answers[17] == b"  M92 X80.00 Y80.00 Z400.00 E500.00\nok\n"
    assert answers[20] == b"  M204 P500.00 R3000.00 T3000.00\nok\n"
    assert answers[21] == b"  M205 B20000.00 S0.00 T0.00 J0.02\nok\n"
    assert answers[23] == b"  M301 P22.00 I1.08 D114.00\nok\n"
    assert answers[27] == b"X:5.00 Y:0.00 Z:0.00 E:0.00 Count X:500 Y:0 Z:0\nok\n"  # M92 X100: 100 steps a mm
    assert answers[28] == answers[29] == answers[27]  # M206 reports the position and shifts nothing until G28
    assert answers[31] == b"  M204 P500.00 R3000.00 T500.00\nok\n"  # S sets P and T
    assert answers[33] == answers[34] == b"Error:?J out of range (0.01 to 0.3)\nok\n"
    assert answers[39].splitlines()[3:] == [
        b"  M92 X100.00 Y80.00 Z400.00 E10.00",
        b"  M203 X300.00 Y300.00 Z5.00 E1250.00",  # M92 E below 20 scales the E feed limit (25 x 500 / 10)
        b"  M201 X1000.00 Y3000.00 Z100.00 E5000.00",
        b"  M204 P500.00 R2000.00 T1000.00",
        b"  M205 B3000.00 S1.00 T2.00 J0.02",
        b"  M206 X5.00 Y0.00 Z-1.00",
        b"  M301 P22.00 I1.00 D100.00",
        b"ok",
    ]
    assert b"echo:  M206 X5.00 Y0.00 Z-1.00\n" in answers[40]  # M503 with its comments reports the same
    assert b"  M92 X80.00 Y80.00 Z400.00 E500.00\n  M203 X300.00 Y300.00 Z5.00 E25.00\n" in answers[42]  # M502
    assert answers[43] == b"X:5.00 Y:0.00 Z:0.00 E:0.00 Count X:400 Y:0 Z:0\nok\n"


def test_the_rounding_script_shows_32_bit_floats_and_cold_extrusion():
    _, sim = sim_transcript(advanced_ok=False, script=ROUNDING_AND_EXTRUSION)
    assert all(got == b"ok\n" for line, got in sim if line == b"G4 P500\n")  # the settling dwells (marlin_replay)
    answers = [normalise(got) for line, got in sim if line != b"G4 P500\n"]
    assert answers[2] == b"X:52.35 Y:0.00 Z:0.00 E:0.00 Count X:4188 Y:0 Z:0\nok\n"  # 64-bit %.2f says 52.34
    assert answers[4] == b"X:0.13 Y:0.00 Z:0.00 E:0.00 Count X:10 Y:0 Z:0\nok\n"  # an exact half rounds up
    assert answers[6] == b"X:10.02 Y:2.67 Z:1.00 E:0.00 Count X:801 Y:214 Z:402\nok\n"
    assert answers[8] == b"X:0.01 Y:0.01 Z:0.00 E:0.00 Count X:1 Y:1 Z:1\nok\n"  # half a step: lroundf, up
    assert answers[12] == b"X:-0.12 Y:-0.14 Z:-0.34 E:0.00 Count X:-50 Y:-9 Z:-1390\nok\n"  # via G92's offset
    assert answers[13] == b"echo: cold extrusion prevented\nok\n"
    assert answers[14] == b"X:5.00 Y:-0.14 Z:-0.34 E:1.00 Count X:361 Y:-9 Z:-1390\nok\n"  # E moved all the same
    assert answers[15] == b"ok\n"  # E1 again in absolute E: no change, no word
    assert answers[19] == answers[20] == b"echo: cold extrusion prevented\nok\n"  # M83: relative, 0.001 is a step
    assert answers[21].startswith(b"X:5.00 Y:-0.14 Z:-0.34 E:0.50 ")
    assert answers[32].startswith(b"X:5.00 Y:-0.14 Z:-0.34 E:1.00 ")  # G90 after M83: absolute again, E1
    assert answers[35].startswith(b"X:1.00 Y:-0.14 Z:-0.34 E:-1.00 ")


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (52.345, "52.35"),  # 52.3450012 as a float
        (2.675, "2.67"),  # 2.6749999
        (0.125, "0.13"),  # exact: half up, where Python's %.2f rounds to even (0.12)
        (-0.125, "-0.13"),
        (-0.004, "-0.00"),
        (1.005, "1.00"),
        (10.015, "10.02"),
        (0.995, "1.00"),  # 0.99500000 as a float: the carry
        (0.0, "0.00"),
    ],
)
def test_marlin_float_prints_as_printfloat(value, text):
    assert marlin_float(value) == text


@given(st.floats(min_value=-1000.0, max_value=1000.0, allow_nan=False))
def test_marlin_float_is_the_32_bit_value_rounded_half_up(value):
    """The printed number is the 32-bit float rounded to hundredths, half away from zero, to within the double
    arithmetic printFloat does (a last-digit slip only at an exact boundary); the sign is the float's."""
    v = f32(value)
    printed = marlin_float(value)
    assert printed.startswith("-") == (v < 0)
    want = math.copysign(math.floor(abs(v) * 100 + 0.5) / 100, v)
    assert abs(float(printed) - want) <= 0.0100001
    assert abs(float(printed) - v) <= 0.0050001


def test_steps_round_half_away_from_zero_as_lroundf():
    assert lround32(0.00625, 80.0) == 1 and lround32(-0.00625, 80.0) == -1  # Python's round() says 0 and 0
    assert lround32(52.345, 80.0) == 4188 and lround32(-0.335 - 3.14034, 400.0) == -1390


def test_slicer_start_code_is_not_refused(protocols_dir):
    """The driver raises CommandRejected on `echo:Unknown command`; a slicer's start code goes through."""
    sim = SimulatedPrinter(load_printer_profile(protocols_dir / "printers" / "paper.toml"))
    driver = MarlinDriver(sim.serial(), config=DriverConfig(boot_timeout_s=0.05, motion_time_scale=0.0))
    start_code = ["M201 X500 Y500 Z100 E5000", "M203 X500 Y500 Z10 E60", "M204 P500 R1000 T500", "M205 J0.02"]
    start_code += ["M92 X80 Y80", "M206 X0 Y0 Z0", "M301 P22.2 I1.08 D114", "M190 S0", "M109 S0", "M110"]
    try:
        driver.connect()
        for command in start_code:
            driver.send(command)
        assert driver.send("M203") == ["M203 X500.00 Y500.00 Z10.00 E60.00"]  # the driver strips the indent
    finally:
        driver.close()
        sim.stop()


def _read_until(fd: int, needle: bytes, deadline_s: float) -> bytes:
    got = b""
    end = time.monotonic() + deadline_s
    while needle not in got and time.monotonic() < end:
        if select.select([fd], [], [], 0.05)[0]:
            got += os.read(fd, 4096)
    return got


def _replies(port: serial.Serial, data: bytes, needle: bytes, deadline_s: float = 5.0) -> bytes:
    port.write(data)
    return _read_until(port.fd, needle, deadline_s)


def _boots(port: serial.Serial) -> bytes:
    """The boot banner a reopened port gets (to its settings report's last line), and the rest of that line."""
    banner = _read_until(port.fd, b"M301", 5.0)
    return banner + _read_until(port.fd, b"\n", 0.3)


@pytest.mark.timeout(60)
def test_a_printer_boots_again_when_a_host_reopens_the_port(protocols_dir):
    """A board with auto-reset reboots on every open (the DTR pulse): the simulator boots (`start`, unhomed, line 0)
    when a host opens the port after the last one closed it (an inotify watch on the pty's path sees both). After
    M112 nothing answers, M999 neither (the real firmware too), until the next open. Before, a reopen of a printer
    that was not halted continued the session: a host found the previous one's homing and settings."""
    sim = SimulatedPrinter(load_printer_profile(protocols_dir / "printers" / "paper.toml"))
    sim.core.take_output()  # the boot banner (a host's open may come before or after the printer writes it)
    path = sim.start_pty()
    try:
        with serial.Serial(path, timeout=0) as port:
            assert _replies(port, b"G28\n", b"ok\n").endswith(b"Count X:0 Y:0 Z:2000\nok\n")
        assert sim.core.resets == 0
        with serial.Serial(path, timeout=0) as port:  # a new host: a new power-on, unhomed
            assert _boots(port).startswith(b"start\n") and sim.core.resets == 1
            assert _replies(port, b"M114\n", b"ok\n") == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"
            assert _replies(port, b"M112\n", b"kill() called!\n").endswith(b"Error:Printer halted. kill() called!\n")
            assert _replies(port, b"M999\nM110 N0\n", b"ok\n", deadline_s=0.5) == b""
        assert sim.core.halted and sim.core.resets == 1
        with serial.Serial(path, timeout=0) as port:
            assert _boots(port).startswith(b"start\n") and sim.core.resets == 2
            assert _replies(port, b"M110 N0\n", b"ok\n") == b"ok\n"
            assert _replies(port, b"M114\n", b"ok\n") == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"
    finally:
        sim.stop()


@pytest.mark.timeout(60)
def test_a_new_host_does_not_inherit_the_last_ones_auto_reports(protocols_dir):
    """The audit's case: OctoPrint left `M155 S2` on, and the next host got temperature reports it never asked for.
    pyserial on the real pty: open, M155 S2, a report, close, open again at once (the close and the open both seen,
    in order): the banner, then no report in 3 s. A host that opens without flushing (a terminal) gets the banner too
    (OPEN_RESET_S after its open)."""
    sim = SimulatedPrinter(load_printer_profile(NATIVE_PROFILE), time_mode="scaled")
    sim.core.take_output()
    path = sim.start_pty()
    report = b" T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0\n"
    try:
        with serial.Serial(path, timeout=0) as port:
            assert _replies(port, b"M155 S2\n", b"ok\n") == b"ok\n"
            assert _read_until(port.fd, report, 5.0).endswith(report)
        with serial.Serial(path, timeout=0) as port:
            assert _boots(port).startswith(b"start\n") and sim.core.resets == 1
            assert report not in _read_until(port.fd, report, 3.0)
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)  # no flush
        try:
            assert _read_until(fd, b"M301", 5.0).startswith(b"start\n") and sim.core.resets == 2
        finally:
            os.close(fd)
    finally:
        sim.stop()


@pytest.mark.timeout(60)
def test_the_cli_printer_resets_on_sigusr1_for_a_host_that_does_not_flush():
    """A terminal program opens without flushing: the CLI's printer stays halted until it gets SIGUSR1."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "neatskin", "sim", "printer", "--time", "virtual"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)  # no tcflush: not a reset
        try:
            _read_until(fd, b"M301", 5.0)  # the boot banner, still in the pty
            os.write(fd, b"M112\n")
            assert _read_until(fd, b"kill() called!\n", 5.0).endswith(b"Error:Printer halted. kill() called!\n")
            os.write(fd, b"M110 N0\n")
            assert _read_until(fd, b"ok\n", 0.5) == b""
            proc.send_signal(signal.SIGUSR1)
            assert _read_until(fd, b"M301", 5.0).startswith(b"start\n")
            _read_until(fd, b"\n", 0.3)
            os.write(fd, b"M110 N0\n")
            assert _read_until(fd, b"ok\n", 5.0) == b"ok\n"
        finally:
            os.close(fd)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)


@pytest.mark.timeout(60)
def test_an_idle_printer_in_virtual_time_keeps_reporting_temperatures(protocols_dir):
    """M155 S1 on a virtual-time printer: the reports keep coming while it is idle, as a real board's do (they
    stopped: the virtual clock stood still, and OctoPrint declared the printer dead); with M155 off, idle time
    leaves the virtual clock where it is (a dry run's clock depends on its commands alone)."""
    sim = SimulatedPrinter(load_printer_profile(NATIVE_PROFILE), time_mode="virtual")
    sim.core.take_output()  # the boot banner
    path = sim.start_pty()
    try:
        with serial.Serial(path, timeout=0) as port:
            assert _replies(port, b"G4 S1\n", b"ok\n") == b"ok\n"
            before = sim.now_s()
            time.sleep(0.3)
            assert sim.now_s() == before == 1.0
            assert _replies(port, b"M155 S1\n", b"ok\n") == b"ok\n"
            reports = _read_until(port.fd, b"B@:0\n T:", 10.0)  # two reports, whenever the machine gets to them
            assert reports.count(b" T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0\n") >= 1 and sim.now_s() > before + 1.0
            assert _replies(port, b"M155 S0\n", b"ok\n").endswith(b"ok\n")
            stopped = sim.now_s()
            time.sleep(0.3)
            assert sim.now_s() == stopped
    finally:
        sim.stop()


@pytest.mark.timeout(60)
def test_the_driver_reconnects_to_a_halted_printer(protocols_dir):
    """This driver's connect() flushes the port's input (as pyserial's open does), so reconnect() after an emergency
    stop finds the printer booted again: unhomed, zeros."""
    profile = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    sim = SimulatedPrinter(profile)
    config = DriverConfig(boot_timeout_s=0.5, motion_time_scale=0.0)
    driver = MarlinDriver.open(sim.start_pty(), 115200, profile=profile, config=config)
    try:
        driver.connect()
        driver.send("G28")
        assert driver.position().z_mm == 5.0
        driver.emergency_stop()
        end = time.monotonic() + 5
        while not sim.core.halted and time.monotonic() < end:
            time.sleep(0.01)
        assert sim.core.halted and sim.core.resets == 0
        driver.reconnect()
        assert sim.core.resets == 1 and driver.position().z_mm == 0.0
    finally:
        driver.close()
        sim.stop()

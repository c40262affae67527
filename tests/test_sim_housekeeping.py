"""The simulated Marlin's host-side commands and text handling, sans-IO on the virtual clock: M155's reports, M113's
keep-alives, the print job timer, M410's quick stop, an arc's end, and how a line's text is read (comments, 95
characters, lower case). tests/test_marlin_real_vs_sim.py holds the same replies to the real firmware."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from neatskin.gcode.profile import load_printer_profile
from neatskin.sim.firmware import QUICK_STOP_HOLD_S, MarlinCore
from neatskin.sim.housekeeping import TEMPERATURES, duration_text

REPORT = (" " + TEMPERATURES + "\n").encode()
BUSY = b"echo:busy: processing\n"


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


def fresh(profile) -> MarlinCore:
    core = MarlinCore(profile)
    core.take_output()
    return core


def talk(core: MarlinCore, data: bytes) -> bytes:
    core.receive(data)
    core.step()
    return core.take_output()


@pytest.mark.parametrize(
    ("seconds", "text"),
    [
        (0, "0s"),
        (59.9, "59s"),
        (60, "1m 0s"),
        (3601, "1h 0m 1s"),
        (86_400 + 61, "1d 0h 1m 1s"),
        (31_536_000, "1y 0d 0h 0m 0s"),
    ],
)
def test_duration_text_is_marlins(seconds, text):
    assert duration_text(seconds) == text


@given(st.integers(0, 10**9))
def test_duration_text_reads_back_to_the_seconds(seconds):
    scale = {"y": 31_536_000, "d": 86_400, "h": 3600, "m": 60, "s": 1}
    words = duration_text(seconds).split()
    assert sum(int(w[:-1]) * scale[w[-1]] for w in words) == seconds
    assert words[-1].endswith("s") and (len(words) == 1 or int(words[0][:-1]) > 0)  # the largest unit leads


def test_m155_reports_every_interval_through_a_dwell_until_s0(profile):
    core = fresh(profile)
    assert talk(core, b"M155 S2\n") == b"ok\n"
    got = talk(core, b"G4 S7\n")  # reports at 2, 4 and 6 s; keep-alives every 2 s; then the ok
    assert got.count(REPORT) == 3 and got.endswith(b"ok\n")
    assert talk(core, b"M155 S0\n") == b"ok\n"
    assert REPORT not in talk(core, b"G4 S7\n")


def test_m113_sets_the_keepalive_interval_and_s0_silences_it(profile):
    core = fresh(profile)
    assert talk(core, b"M113\n") == b"echo:M113 S2\nok\n"
    assert talk(core, b"G4 S5\n").count(BUSY) == 2
    assert talk(core, b"M113 S1\n") == b"ok\n"
    assert talk(core, b"M113\n") == b"echo:M113 S1\nok\n"
    assert talk(core, b"M113 S0\n") == b"ok\n"
    assert talk(core, b"G4 S5\n") == b"ok\n"


def test_the_print_job_timer_runs_pauses_and_stops(profile):
    core = fresh(profile)
    assert talk(core, b"M31\n") == b"echo:Print time: 0s\nok\n"
    talk(core, b"M75\n")
    talk(core, b"G4 S65\n")
    assert talk(core, b"M31\n") == b"echo:Print time: 1m 5s\nok\n"
    talk(core, b"M76\n")
    talk(core, b"G4 S100\n")  # paused: not counted
    talk(core, b"M75\n")
    talk(core, b"G4 S5\n")
    talk(core, b"M77\n")
    talk(core, b"G4 S100\n")  # stopped: the time stays
    assert talk(core, b"M31\n") == b"echo:Print time: 1m 10s\nok\n"
    talk(core, b"M75\n")  # a start after a stop counts from zero
    talk(core, b"G4 S3\n")
    assert talk(core, b"M31\n") == b"echo:Print time: 3s\nok\n"


def test_settings_commands(profile):
    core = fresh(profile)
    assert talk(core, b"M500\n") == b"Warning:EEPROM disabled\nok\n"
    assert talk(core, b"M502\n") == b"echo:Hardcoded Default Settings Loaded\nok\n"
    full = talk(core, b"M503\n").splitlines()
    bare = talk(core, b"M503 S0\n").splitlines()
    assert full[0] == b"echo:; Linear Units:" and full[-1] == b"ok" and len(full) == 21
    assert bare[:-1] == [line[len(b"echo:") :] for line in full[1:-1:2]]  # the commands, without echo: or headings
    assert talk(core, b"M501\n").splitlines() == [b"echo:Hardcoded Default Settings Loaded"] + full


def test_m410_stops_the_motion_where_the_probe_is(profile):
    core = fresh(profile)
    talk(core, b"G28\n")
    talk(core, b"M400\n")
    start = core.timeline.position_mm(core.clock.now())
    talk(core, b"G1 X100 F600\n")  # 10 mm/s: ten seconds of travel queued
    t0 = core.clock.now()
    core.clock.wait_until(t0 + 2.0)
    here = core.timeline.position_mm(core.clock.now())
    assert 5.0 < here[0] - start[0] < 25.0
    assert talk(core, b"M410\n") == b"ok\n"
    assert core.clock.now() == pytest.approx(t0 + 2.0 + QUICK_STOP_HOLD_S)  # the planner held for a second
    assert talk(core, b"M400\n") == b"ok\n" and core.clock.now() == pytest.approx(t0 + 2.0 + QUICK_STOP_HOLD_S)
    report = talk(core, b"M114\n").decode()
    assert report.startswith(f"X:{here[0]:.2f} Y:{here[1]:.2f} Z:{here[2]:.2f} ")  # it believes where it stopped
    assert core.timeline.position_mm(core.clock.now() + 20.0) == pytest.approx(here)


def test_an_unnumbered_m410_stops_the_motion_as_it_is_read(profile):
    """queue.cpp's early commands: an M410 read while an M400 waits in the queue stops the motion at once."""
    core = fresh(profile)
    talk(core, b"G28\n")
    talk(core, b"M400\n")
    assert talk(core, b"G1 X100 F600\n") == b"ok\n"
    core.receive(b"M400\n")  # queued, not run yet
    core.clock.wait_until(core.clock.now() + 2.0)
    here = core.timeline.position_mm(core.clock.now())
    core.receive(b"M410\n")
    assert core.timeline.end_s == core.clock.now() and core.timeline.end_mm == pytest.approx(here)
    core.step()
    assert core.take_output() == b"ok\nok\n"  # the M400 (the motion is over), then the M410


def test_an_arc_ends_at_its_end_point(profile):
    core = fresh(profile)
    talk(core, b"G28\n")
    talk(core, b"G1 X10 Y10 F6000\n")
    talk(core, b"G2 X20 Y10 I5 J0\n")
    talk(core, b"M400\n")
    assert talk(core, b"M114\n").startswith(b"X:20.00 Y:10.00 ")


def test_line_text_as_marlin_reads_it(profile):
    core = fresh(profile)
    assert talk(core, b";a comment\n") == b""
    assert talk(core, b"\r\n") == b""
    assert talk(core, b"  \n") == b'echo:Unknown command: ""\nok\n'
    assert talk(core, b"g28\n") == b'echo:Unknown command: "g28"\nok\n'
    assert talk(core, b"G92 X1 y2 Z3 ; set\n") == b"X:1.00 Y:0.00 Z:3.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"
    assert talk(core, b"M118 E1 kept ; not this\n") == b"echo:kept \r\nok\n"
    assert talk(core, b"M118 E1 " + b"x" * 100 + b"\n") == b"echo:" + b"x" * 87 + b"\r\nok\n"
    assert talk(core, b"T0\n") == talk(core, b"M108\n") == b"ok\n"

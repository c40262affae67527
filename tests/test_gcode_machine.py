"""The one G-code machine model: positions after G91/G92/G28 sequences and trapezoid times, computed by hand.

The paper profile: accel 500 mm/s^2; max feed x, y 500, z 5 mm/s; max accel x, y 500, z 100 mm/s^2;
homing 25 s. `shifted` moves the soft minimum (Marlin's X_HOME_POS for min endstops) to (5, 10, 1)
so that "home" and "zero" differ.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from neatskin.gcode.bounds import check_commands, check_moves
from neatskin.gcode.machine import Dwell, Home, Machine, Move, SetPosition, Sync
from neatskin.gcode.motion import MotionClock
from neatskin.gcode.parse import checksum, parse_line
from neatskin.gcode.profile import Axes, load_printer_profile
from neatskin.marlin.deadlines import MotionTracker
from neatskin.sim.firmware import MarlinCore


@pytest.fixture(scope="module")
def shifted(protocols_dir):
    profile = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    return replace(profile, soft_min_mm=Axes(5.0, 10.0, 1.0), park_mm=Axes(5.0, 200.0, 60.0))


def run(machine: Machine, *commands: str) -> list:
    return [machine.step(parse_line(c)) for c in commands]


def test_a_hand_computed_program(shifted):
    m = Machine(shifted, homing_time_s=shifted.homing_time_s)
    (home,) = run(m, "G28")
    assert home == Home((0, 1, 2), (None, None, None), (5.0, 10.0, 1.0), 25.0)
    _, move = run(m, "G91", "G1 X100 F6000")
    # 100 mm/s, 500 mm/s^2: 20 mm to speed up and slow down < 100 mm: 0.2 s + 80 mm at 100 mm/s
    assert move.end_mm == (105.0, 10.0, 1.0) and move.duration_s == pytest.approx(1.2, abs=1e-12)
    (g92,) = run(m, "G92 X0")
    assert g92 == SetPosition((0.0, None, None))
    assert m.position_mm == [105.0, 10.0, 1.0] and m.logical_mm == (0.0, 10.0, 1.0)
    _, move = run(m, "G90", "G1 X10")  # logical 10 = native 115; 10 mm < 20 mm: a triangle, 2 sqrt(10/500)
    assert move.end_mm == (115.0, 10.0, 1.0) and move.duration_s == pytest.approx(0.282842712474619, abs=1e-12)
    (move,) = run(m, "G1 Z3 F600")  # z caps 10 mm/s at 5 and 100 mm/s^2: 2 x 0.05 s ramps + 1.75 mm / 5
    assert (move.feed_mm_s, move.accel_mm_s2) == (5.0, 100.0)
    assert move.duration_s == pytest.approx(0.45, abs=1e-12)
    (home,) = run(m, "G28 X")  # homes X only: native 5, its G92 offset cleared, a third of the homing time
    assert home.axes == (0,) and home.end_mm == (5.0, 10.0, 3.0) and home.duration_s == pytest.approx(25 / 3)
    assert m.logical_mm == (5.0, 10.0, 3.0)
    (move,) = run(m, "G1 X10")  # the modal F600: 5 mm at 10 mm/s, 0.1 mm ramps: 0.02 s + 0.5 s
    assert move.start_mm == (5.0, 10.0, 3.0) and move.duration_s == pytest.approx(0.52, abs=1e-12)
    (move,) = run(m, "G1 X13 Z7")  # (3, 0, 4): z share 0.8 caps feed at 6.25 mm/s and accel at 125 mm/s^2
    assert (move.feed_mm_s, move.accel_mm_s2) == (6.25, 125.0)
    assert move.length_mm == 5.0 and move.duration_s == pytest.approx(0.05 + 0.8, abs=1e-12)
    assert run(m, "G4 P500", "G4 S2", "M400") == [Dwell(0.5), Dwell(2.0), Sync()]


def test_unknown_position_until_homed_or_moved_absolutely(shifted):
    m = Machine(shifted)
    _, move = run(m, "G91", "G1 X5")
    assert move.end_mm == (None, None, None) and move.duration_s is None
    _, move = run(m, "G90", "G1 X10")  # known from now on, but the move itself came from nowhere known
    assert move.end_mm == (10.0, None, None) and move.duration_s is None
    (g92,) = run(m, "G92 Z0")  # nothing known: the logical position is taken as native
    assert m.position_mm == [10.0, None, 0.0] and m.offset_mm == [0.0, 0.0, 0.0]
    assert isinstance(g92, SetPosition)


def test_limits_clamp_the_native_target(shifted):
    m = Machine(shifted, limits_mm=((5.0, 10.0, 1.0), (220.0, 220.0, 250.0)))
    _, move = run(m, "G28", "G1 X300 Y-5")
    assert move.requested_mm == (300.0, -5.0, 1.0) and move.end_mm == (220.0, 10.0, 1.0) and move.clamped


def test_without_a_profile_home_is_zero_and_no_axis_limits():
    m = Machine(accel_mm_s2=200.0, feed_mm_s=25.0)
    _, move = run(m, "G28", "G1 Z10")  # 25 mm/s at 200 mm/s^2: 3.125 mm ramps: 0.125 s + 10 mm / 25
    assert move.start_mm == (0.0, 0.0, 0.0) and move.duration_s == pytest.approx(0.125 + 0.4, abs=1e-12)


# Z ends above 5 mm: the simulated printer's G28 then raises nothing (Marlin's G28 lifts Z to 5 mm before homing
# X or Y and after homing Z; the machine model's G28 does not: see test_marlin_real_vs_sim's HOMING)
PROGRAM = ("G28", "G91", "G1 X20 Y30 F3000", "G92 X0", "G90", "G1 X7 Z6", "G28 Y", "G1 Y15", "M400")


def test_every_consumer_agrees_on_home_and_g92(shifted):
    """The estimate, the host's deadlines, the bounds check and the simulated printer step the same model."""
    logical = (7.0, 15.0, 6.0)
    native = (32.0, 15.0, 6.0)  # X: home 5 + 20 relative, G92 X0 there, X7 logical -> 32 native
    clock = MotionClock(shifted)
    tracker = MotionTracker(shifted)
    for command in PROGRAM:
        clock.step(command)
        tracker.line_time_s(command)
    assert tuple(clock.machine.position_mm) == native and clock.machine.logical_mm == logical
    assert tuple(tracker.position_mm) == logical
    core = MarlinCore(shifted)
    for n, command in enumerate(PROGRAM, start=1):
        body = f"N{n} {command}"
        core.receive(f"{body}*{checksum(body)}\n".encode())
        core.step()
    core.take_output()
    core.receive(b"M114\n")
    core.step()
    assert core.take_output().startswith(b"X:7.00 Y:15.00 Z:6.00 E:0.00 Count X:2560 Y:1200 Z:2400\nok\n")
    assert core.timeline.end_mm == native
    lines = [parse_line(c) for c in PROGRAM]
    assert check_moves(shifted, lines) == []  # every native target is inside the bed and the soft limits
    assert [p.field for p in check_commands(lines)] == ["command 4"]  # the G92 is refused by the command check


def test_g28_homes_to_the_profiles_home_in_the_estimate(shifted):
    clock = MotionClock(shifted, start_mm=(100.0, 100.0, 50.0))
    clock.step("G28")
    seconds = clock.step("G1 X5 Y10 Z11 F600")  # from home (5, 10, 1): a pure 10 mm z move
    assert seconds == pytest.approx(2 * 0.05 + 9.75 / 5, abs=1e-12)  # ramps of 0.25 mm, 9.5 mm cruise
    assert clock.estimate().homing_s == 25.0


def test_move_event_is_a_frozen_value():
    move = Move((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 0.0, 0.0), 10.0, 100.0, 1.0, 0.2)
    with pytest.raises(AttributeError):
        move.duration_s = 1.0  # type: ignore[misc]
    assert not move.clamped and math.isclose(move.length_mm, 1.0)


def test_host_deadlines_from_the_model(shifted):
    tracker = MotionTracker(shifted)
    # unknown start: 500 mm on the slowest axis (5 mm/s, 100 mm/s^2): 2 x 0.05 s ramps + 499.75 mm / 5
    assert tracker.line_time_s("G1 X10") == (pytest.approx(100.05, abs=1e-9), False)
    assert tracker.line_time_s("G28") == (60.0, True)  # the host's bound: max(60, 2 x 25 s)
    assert tracker.position_mm == [5.0, 10.0, 1.0]
    # from home (5, 10, 1) to x = 15: 10 mm at 100 mm/s, 500 mm/s^2 is a triangle, 2 sqrt(10 / 500)
    seconds, waits = tracker.line_time_s("G1 X15 F6000")
    assert seconds == pytest.approx(0.282842712474619, abs=1e-12) and not waits
    assert tracker.line_time_s("G4 P250") == (0.25, True) and tracker.line_time_s("M400") == (0.0, True)
    assert tracker.line_time_s("; comment") == (0.0, False) and tracker.line_time_s("G1 X1e999") == (0.0, True)

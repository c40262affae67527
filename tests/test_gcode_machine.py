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
from neatskin.gcode.machine import Dwell, Machine, Move, SetPosition, Sync
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
    # Z at its homing feed, 4 mm/s and 100 mm/s^2: 0.04 s ramps over 0.08 mm each. Unhomed, Z first rises 5 mm
    # from an unknown height (0.08 s + 4.84 mm / 4); once homed at 1 it moves to 5 (0.08 s + 3.84 mm / 4)
    assert home.axes == (0, 1, 2) and home.start_mm == (None, None, None) and home.end_mm == (5.0, 10.0, 5.0)
    assert home.rise is not None and home.rise.end_mm == (None, None, None) and home.rise.length_mm == 5.0
    assert home.rise.duration_s == pytest.approx(0.08 + 4.84 / 4, abs=1e-12)
    assert home.after is not None and (home.after.start_mm, home.after.end_mm) == ((5.0, 10.0, 1.0), home.end_mm)
    assert home.after.duration_s == pytest.approx(0.08 + 3.84 / 4, abs=1e-12)
    assert home.duration_s == 25.0 and home.homing_s == pytest.approx(25.0 - 1.29 - 1.04, abs=1e-12)
    _, move = run(m, "G91", "G1 X100 F6000")
    # 100 mm/s, 500 mm/s^2: 20 mm to speed up and slow down < 100 mm: 0.2 s + 80 mm at 100 mm/s
    assert move.end_mm == (105.0, 10.0, 5.0) and move.duration_s == pytest.approx(1.2, abs=1e-12)
    (g92,) = run(m, "G92 X0")
    assert g92 == SetPosition((0.0, None, None))
    assert m.position_mm == [105.0, 10.0, 5.0] and m.logical_mm == (0.0, 10.0, 5.0)
    _, move = run(m, "G90", "G1 X10")  # logical 10 = native 115; 10 mm < 20 mm: a triangle, 2 sqrt(10/500)
    assert move.end_mm == (115.0, 10.0, 5.0) and move.duration_s == pytest.approx(0.282842712474619, abs=1e-12)
    (move,) = run(m, "G1 Z3 F600")  # z caps 10 mm/s at 5 and 100 mm/s^2: 2 x 0.05 s ramps + 1.75 mm / 5
    assert (move.feed_mm_s, move.accel_mm_s2) == (5.0, 100.0)
    assert move.duration_s == pytest.approx(0.45, abs=1e-12)
    # homes X only: Z (homed, at 3) first rises to 5 (0.08 s + 1.84 mm / 4); X native 5, its G92 offset cleared;
    # a third of the homing time
    (home,) = run(m, "G28 X")
    assert home.axes == (0,) and home.end_mm == (5.0, 10.0, 5.0) and home.duration_s == pytest.approx(25 / 3)
    assert home.rise is not None and home.rise.duration_s == pytest.approx(0.08 + 1.84 / 4, abs=1e-12)
    assert home.after is None and m.logical_mm == (5.0, 10.0, 5.0)
    (move,) = run(m, "G1 X10")  # the modal F600: 5 mm at 10 mm/s, 0.1 mm ramps: 0.02 s + 0.5 s
    assert move.start_mm == (5.0, 10.0, 5.0) and move.duration_s == pytest.approx(0.52, abs=1e-12)
    (move,) = run(m, "G1 X13 Z9")  # (3, 0, 4): z share 0.8 caps feed at 6.25 mm/s and accel at 125 mm/s^2
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
    _, move = run(m, "G28", "G1 X300 Y-5")  # G28 leaves Z at 5 (Z_POST_CLEARANCE)
    assert move.requested_mm == (300.0, -5.0, 5.0) and move.end_mm == (220.0, 10.0, 5.0) and move.clamped


def test_without_a_profile_home_is_zero_and_no_axis_limits():
    m = Machine(accel_mm_s2=200.0, feed_mm_s=25.0)
    _, move = run(m, "G28", "G1 Z10")  # 25 mm/s at 200 mm/s^2: 3.125 mm ramps: 0.125 s + 10 mm / 25
    assert move.start_mm == (0.0, 0.0, 0.0) and move.duration_s == pytest.approx(0.125 + 0.4, abs=1e-12)


# Z goes down to 2 mm, so the G28 Y lifts it to 5 first (Marlin's G28: Z_CLEARANCE_FOR_HOMING once Z is homed),
# in every consumer (see also test_marlin_real_vs_sim's HOMING)
PROGRAM = ("G28", "G91", "G1 X20 Y30 F3000", "G92 X0", "G90", "G1 X7 Z2", "G28 Y", "G1 Y15", "M400")


def test_every_consumer_agrees_on_home_and_g92(shifted):
    """The estimate, the host's deadlines, the bounds check and the simulated printer step the same model."""
    logical = (7.0, 15.0, 5.0)
    native = (32.0, 15.0, 5.0)  # X: home 5 + 20 relative, G92 X0 there, X7 logical -> 32 native; Z: 2, raised to 5
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
    assert core.take_output().startswith(b"X:7.00 Y:15.00 Z:5.00 E:0.00 Count X:2560 Y:1200 Z:2000\nok\n")
    assert core.timeline.end_mm == native
    lines = [parse_line(c) for c in PROGRAM]
    assert check_moves(shifted, lines) == []  # every native target is inside the bed and the soft limits
    assert [p.field for p in check_commands(lines)] == ["command 4"]  # the G92 is refused by the command check


def test_g28_homes_to_the_profiles_home_in_the_estimate(shifted):
    clock = MotionClock(shifted, start_mm=(100.0, 100.0, 50.0))
    clock.step("G28")
    # from home (5, 10, 1), Z then moved to 5 (Z_POST_CLEARANCE): a pure 6 mm z move
    seconds = clock.step("G1 X5 Y10 Z11 F600")
    assert seconds == pytest.approx(2 * 0.05 + 5.75 / 5, abs=1e-12)  # ramps of 0.25 mm, 5.5 mm cruise
    assert clock.estimate().homing_s == 25.0  # the measured whole G28, its Z moves (1.29 s + 1.04 s) inside


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
    assert tracker.position_mm == [5.0, 10.0, 5.0]  # home (5, 10, 1), then Z to 5 (Z_POST_CLEARANCE)
    # from (5, 10, 5) to x = 15: 10 mm at 100 mm/s, 500 mm/s^2 is a triangle, 2 sqrt(10 / 500)
    seconds, waits = tracker.line_time_s("G1 X15 F6000")
    assert seconds == pytest.approx(0.282842712474619, abs=1e-12) and not waits
    assert tracker.line_time_s("G4 P250") == (0.25, True) and tracker.line_time_s("M400") == (0.0, True)
    assert tracker.line_time_s("; comment") == (0.0, False) and tracker.line_time_s("G1 X1e999") == (0.0, True)


def test_g28_r_raises_relative_to_z_before_any_homing_and_r0_not_at_all(shifted):
    """G28's R word as G28.cpp's seenR (and as the native build answers: test_g28_with_an_r_word_answers_as_the_real_
    firmware): the raise is R, relative to Z even once Z is homed, before Z's own homing too; R0 raises nothing."""
    m = Machine(shifted, start_mm=(50.0, 50.0, 20.0))
    run(m, "G28", "G1 Z20")
    (home,) = run(m, "G28 X R3")
    assert home.rise is not None and home.rise.end_mm == (5.0, 10.0, 23.0) and home.end_mm == (5.0, 10.0, 23.0)
    (home,) = run(m, "G28 Y R0")
    assert home.rise is None and home.end_mm == (5.0, 10.0, 23.0)
    (home,) = run(m, "G28 Z R2")  # up 2 first (a Z-only G28 raises nothing without R), home at 1, then to 5
    assert home.rise is not None and home.rise.end_mm == (5.0, 10.0, 25.0) and home.end_mm == (5.0, 10.0, 5.0)
    (home,) = run(m, "G28 Z")
    assert home.rise is None


def test_a_g28_takes_at_least_its_z_moves(shifted):
    """`homing_time_s` is a whole G28 as measured, raises included: a homing time shorter than G28's Z moves (at
    Z's homing feed, 4 mm/s, 100 mm/s^2) gives way to them, in the machine, the estimate and the firmware alike."""
    quick = replace(shifted, homing_time_s=0.5)
    m = Machine(quick, start_mm=(50.0, 50.0, 20.0), homing_time_s=quick.homing_time_s)
    (home,) = run(m, "G28")  # unhomed at 20: up to 25 (0.08 s + 4.84 mm / 4), home at 1, then to 5 (3.84 mm)
    assert home.rise is not None and home.rise.end_mm == (50.0, 50.0, 25.0)
    assert home.duration_s == pytest.approx(0.08 + 4.84 / 4 + 0.08 + 3.84 / 4, abs=1e-12) and home.homing_s == 0.0
    clock = MotionClock(quick, start_mm=(50.0, 50.0, 20.0))
    assert clock.step("G28") == home.duration_s and clock.estimate().homing_s == home.duration_s
    core = MarlinCore(quick)
    before = core.clock.now()
    core.receive(b"G28\nM400\n")
    for _ in range(100):  # a cap: the virtual clock jumps to when each command is done
        core.step()
    assert core.take_output().count(b"ok\n") == 2
    # the firmware believes zeros at boot: up 5 from 0, home, up 4 from 1: 1.29 s + 1.04 s, more than 0.5 s
    assert core.timeline.end_s - before == pytest.approx(0.08 + 4.84 / 4 + 0.08 + 3.84 / 4, abs=1e-9)


def test_a_zero_clearance_raises_only_a_homed_z_below_0(shifted):
    """A profile with `z_clearance_for_homing_mm = 0` raises nothing above 0; `z_after_homing_mm` at Z's home (1
    here: the post-homing move goes to that native height, so 0, the clearance, would move down) leaves Z there;
    a homed Z below 0 rises to 0, as G28.cpp's do_z_clearance(0) does."""
    m = Machine(replace(shifted, z_clearance_for_homing_mm=0.0, z_after_homing_mm=1.0), start_mm=(50.0, 50.0, 20.0))
    (home,) = run(m, "G28 X")
    assert home.rise is None and home.after is None and home.end_mm == (5.0, 50.0, 20.0)
    (home,) = run(m, "G28")
    assert home.rise is None and home.after is None and home.end_mm == (5.0, 10.0, 1.0)
    # Z homed and below its home (no soft endstops: M211 S0): G28.cpp's do_z_clearance(0) still raises it, to 0
    # native, as the native firmware built with Z_CLEARANCE_FOR_HOMING 0 does (`G1 Z-1`, `G28 Y` -> Z 0)
    free = Machine(replace(shifted, z_clearance_for_homing_mm=0.0), start_mm=(50.0, 50.0, 20.0))
    run(free, "G28", "G1 Z-1")
    (home,) = run(free, "G28 Y")
    assert home.rise is not None and home.rise.end_mm == (5.0, 10.0, 0.0) and home.end_mm == (5.0, 10.0, 0.0)
    assert home.rise.start_mm == (5.0, 10.0, -1.0) and home.rise.length_mm == 1.0
    (home,) = run(free, "G28 X")  # at 0 now: nothing to raise
    assert home.rise is None and home.end_mm == (5.0, 10.0, 0.0)
    low = Machine(replace(shifted, z_after_homing_mm=2.0), start_mm=(50.0, 50.0, 20.0))
    (home,) = run(low, "G28 Z")  # Z alone: no raise; Z_AFTER_HOMING 2 from home 1
    assert home.rise is None and home.after is not None and home.end_mm == (50.0, 50.0, 2.0)

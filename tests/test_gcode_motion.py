"""Motion-time estimates against hand computations."""

import math

import pytest

from neatskin.gcode.machine import limited_feed_and_accel, trapezoid_time_s
from neatskin.gcode.motion import estimate_program_time
from neatskin.gcode.profile import load_printer_profile


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


def test_trapezoidal_move_by_hand():
    # 100 mm at 100 mm/s, 500 mm/s^2: accelerate 0.2 s over 10 mm, cruise 80 mm in 0.8 s, brake 0.2 s
    assert trapezoid_time_s(100.0, 100.0, 500.0) == pytest.approx(0.2 + 0.8 + 0.2, abs=1e-12)


def test_triangular_move_by_hand():
    # 10 mm at 100 mm/s, 500 mm/s^2 never reaches 100 mm/s: peak sqrt(500*10) = 70.71 mm/s
    v_peak = math.sqrt(500.0 * 10.0)
    assert trapezoid_time_s(10.0, 100.0, 500.0) == pytest.approx(2 * v_peak / 500.0, abs=1e-12)
    assert trapezoid_time_s(10.0, 100.0, 500.0) == pytest.approx(0.28284271247, abs=1e-10)


def test_start_and_end_speeds():
    # from 50 mm/s to 100 mm/s (7.5 mm), cruise, down to 0 (10 mm): 100 mm total
    t = trapezoid_time_s(100.0, 100.0, 500.0, v_start_mm_s=50.0)
    assert t == pytest.approx(0.1 + 82.5 / 100 + 0.2, abs=1e-12)
    assert trapezoid_time_s(0.0, 10.0, 10.0) == 0.0
    with pytest.raises(ValueError):
        trapezoid_time_s(0.1, 100.0, 10.0, v_start_mm_s=100.0)
    with pytest.raises(ValueError):
        trapezoid_time_s(-1.0, 10.0, 10.0)


def test_axis_limits_scale_a_z_move(profile):
    # a pure Z move asked for at 100 mm/s runs at the Z maxima (5 mm/s, 100 mm/s^2)
    assert limited_feed_and_accel((0.0, 0.0, 10.0), 100.0, profile) == (5.0, 100.0)
    # 10 mm of Z at 5 mm/s, 100 mm/s^2: 0.05 s + 9.75 mm / 5 + 0.05 s
    est = estimate_program_time(["G90", "G1 Z20 F6000", "G1 Z10"], profile, start_mm=(0.0, 0.0, 10.0))
    per_move = 0.05 + 9.75 / 5.0 + 0.05
    assert est.motion_s == pytest.approx(2 * per_move, abs=1e-12)
    assert est.moves == 2 and est.path_mm == pytest.approx(20.0)


def test_program_estimate_counts_dwell_and_homing(profile):
    est = estimate_program_time(["G28", "G4 P500", "G4 S2", "G91", "G1 X100 F6000", "G1 X-100"], profile)
    assert est.homing_s == profile.homing_time_s
    assert est.dwell_s == pytest.approx(2.5)
    # 100 mm at 100 mm/s (F6000), 500 mm/s^2: 1.2 s each, back and forth
    assert est.motion_s == pytest.approx(2.4, abs=1e-12)
    assert est.total_s == pytest.approx(2.4 + 2.5 + profile.homing_time_s)
    assert est.travel_xy_mm == pytest.approx(200.0)


def test_phase_durations_by_hand(profile, paper_layout):
    from neatskin.gcode.motion import phase_durations_s
    from neatskin.gcode.positions import PositionSet
    from neatskin.gcode.program import PressSpec, build_program

    ps = PositionSet((10.0,), (0.0,), ("channel:J00-J10",))
    prog = build_program(paper_layout, ps, PressSpec(depth_mm=3.5, repeats=2, hold_s=0.5), profile, hold_in_gcode=True)
    d = phase_durations_s(prog, profile)
    # after G28 the probe is at (0, 0, 5) (home, then Z_POST_CLEARANCE): up 10.5 mm at Z limits, then 105 x 95
    # mm of travel at 100 mm/s
    up = 0.05 + (10.5 - 0.25) / 5 + 0.05
    xy = 2 * 0.2 + (((105.0**2 + 95.0**2) ** 0.5) - 20.0) / 100.0
    descend = 0.05 + 9.75 / 5 + 0.05  # 10 mm at 5 mm/s, 100 mm/s^2
    press = 0.02 + 3.46 / 2 + 0.02 + 0.5  # 3.5 mm at 2 mm/s, then the 0.5 s hold
    lift = 0.05 + 13.25 / 5 + 0.05  # 13.5 mm back up
    assert d.shape == (2, 4)
    assert d[0] == pytest.approx([up + xy, descend, press, lift], abs=1e-9)
    assert d[1] == pytest.approx([0.0, descend, press, lift], abs=1e-9)
    total = estimate_program_time(prog.command_lines(), profile).total_s
    assert total == pytest.approx(
        d.sum()
        + profile.homing_time_s
        + estimate_program_time(prog.postamble, profile, start_mm=(105.0, 95.0, 15.5)).total_s
    )


def test_phase_durations_of_a_paper_campaign_equal_stepping_parsed_lines(profile, paper_layout):
    """The clock's parse cache and its echo shortcut change no number: every phase of 200 presses equals,
    to the bit, the sum over lines parsed one by one and stepped on a fresh machine."""
    import numpy as np

    from neatskin.gcode.motion import MotionClock, phase_durations_s
    from neatskin.gcode.parse import parse_line
    from neatskin.gcode.positions import PositionSet
    from neatskin.gcode.program import PressSpec, build_program

    rng = np.random.default_rng(3)
    xs, ys = rng.uniform(0, 30, 100), rng.uniform(0, 30, 100)
    ps = PositionSet(tuple(xs), tuple(ys), tuple("random" for _ in xs))
    prog = build_program(paper_layout, ps, PressSpec(depth_mm=3.5, repeats=2, hold_s=1.2), profile)
    fast = phase_durations_s(prog, profile)
    clock = MotionClock(profile)
    for line in prog.preamble:
        clock.step(parse_line(line))
    slow = np.array(
        [
            [sum(clock.step(parse_line(line)) for line in phase.lines) for phase in block.phases]
            for block in prog.presses
        ]
    )
    assert fast.shape == (200, 4) and np.array_equal(fast, slow)
    assert any(line.startswith("M118 ") for line in prog.presses[0].phases[0].lines)  # the shortcut was taken


def test_the_clock_still_refuses_a_malformed_line(profile):
    from neatskin.gcode.motion import MotionClock
    from neatskin.gcode.parse import GcodeSyntaxError

    clock = MotionClock(profile)
    assert clock.step("M118 E1 hello") == 0.0
    with pytest.raises(GcodeSyntaxError):
        clock.step("M118 E1 hello*x")
    with pytest.raises(GcodeSyntaxError):
        clock.step("G1 Xnan")
    with pytest.raises(GcodeSyntaxError):
        clock.step("G1 Xnan")  # a refused line is not cached as a good one

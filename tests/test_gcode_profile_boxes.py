"""One soft box per printer profile (PrinterProfile.soft_box_mm): `gcode check` refuses outside it and the simulated
printer, once homed, clamps to it; the travel box (the bed, the z soft limits) is where its steppers stop unhomed."""

from __future__ import annotations

from dataclasses import replace

from neatskin.gcode.bounds import check_moves
from neatskin.gcode.parse import parse_program
from neatskin.gcode.profile import Axes, load_printer_profile
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.sim.printer import SimulatedPrinter


def _profile(protocols_dir):
    """The paper printer (bed 220 x 220) with soft limits inside the bed: x 5..190, y 10..150, z 0..120."""
    paper = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    return replace(
        paper, soft_min_mm=Axes(5.0, 10.0, 0.0), soft_max_mm=Axes(190.0, 150.0, 120.0), park_mm=Axes(100.0, 100.0, 50.0)
    )


def test_the_boxes_are_the_bed_and_the_soft_limits_intersected(protocols_dir):
    profile = _profile(protocols_dir)
    assert profile.travel_box_mm == ((0.0, 0.0, 0.0), (220.0, 220.0, 120.0))
    assert profile.soft_box_mm == ((5.0, 10.0, 0.0), (190.0, 150.0, 120.0))
    assert profile.soft_box_mm is profile.soft_box_mm  # built once per profile


def test_check_and_simulator_use_the_same_soft_box(protocols_dir):
    profile = _profile(protocols_dir)
    inside = "G28\nG1 X190 Y150 Z100 F3000\nG1 X5 Y10\n"
    assert check_moves(profile, parse_program(inside)) == []
    for outside, axis in (("G1 X190.5 Y20", "X"), ("G1 X4.5 Y20", "X"), ("G1 X20 Y9.5", "Y"), ("G1 X20 Y150.5", "Y")):
        problems = check_moves(profile, parse_program(f"G28\n{outside}\n"))
        assert [p.message.split(" moves ")[1][0] for p in problems] == [axis]
    sim = SimulatedPrinter(profile, seed=0)
    driver = MarlinDriver(sim.serial(), profile=profile, config=DriverConfig(motion_time_scale=0))
    try:
        driver.connect(boot_timeout_s=0.2)
        driver.send_lines(["G28", "G1 X215 Y5 Z20 F3000", "M400"])
        at = driver.position()
        assert (at.x_mm, at.y_mm, at.z_mm) == (190.0, 10.0, 20.0)  # the firmware clamps to the soft box
        assert sim.probe_position(sim.now_s()) == (190.0, 10.0, 20.0)
    finally:
        driver.close()
        sim.stop()

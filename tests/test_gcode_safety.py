"""Refusals before any text: out-of-bounds targets, too-deep presses, over-fast feeds, injected names."""

from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.errors import ConfigError
from neatskin.gcode import emit
from neatskin.gcode.bounds import check_commands, check_moves, check_phases
from neatskin.gcode.calibration import Calibration
from neatskin.gcode.parse import parse_program
from neatskin.gcode.positions import PositionSet, PositionSpec, generate_positions
from neatskin.gcode.profile import load_printer_profile
from neatskin.gcode.program import PressSpec, build_program
from neatskin.gcode.spec import press_spec_from_dict


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


@pytest.fixture(scope="module")
def positions(paper_layout):
    return generate_positions(paper_layout, PositionSpec("paper", 10, 11))


@pytest.fixture()
def no_text(monkeypatch):
    """Fail the test if any G-code text is formatted."""
    calls = []

    def spy(*args, **kwargs):
        calls.append(args)
        raise AssertionError("G-code text was formatted before the refusal")

    for name in ("fmt", "feed", "marker", "program_text"):
        monkeypatch.setattr(emit, name, spy)
    return calls


def refuse(layout, positions, profile, press=PressSpec(depth_mm=3.5, repeats=2), **kwargs):
    with pytest.raises(ConfigError) as info:
        build_program(layout, positions, press, profile, **kwargs)
    return info.value


def test_position_off_the_bed_names_press_and_limit(paper_layout, profile, no_text):
    # the skin's corner at printer x = -5: every press at sensor x < 5 is off the bed
    ps = PositionSet((2.0, 20.0), (15.0, 15.0), ("face:0", "face:1"))
    shifted = profile.with_calibration(Calibration(-5.0, 95.0, 0.0, 5.5))
    err = refuse(paper_layout, ps, shifted)
    # one problem per axis, not one per press: a wrong offset is one mistake
    assert [p.field for p in err.problems] == ["press 0"]
    assert str(err.problems[0]).endswith(
        "press 0 (position 0) goes to printer x = -3.000 mm, outside the bed and soft limits [0, 220] mm; "
        "so does 1 more press (1 position in all, x from -3.000 to -3.000 mm) "
        "(fix: move the skin or refit the calibration offset/rotation (printer profile [calibration]) "
        "so every position lands on the bed)"
    )


@pytest.mark.parametrize(
    "calibration, axis",
    [
        (Calibration(200.0, 95.0, 0.0, 5.5), "x"),  # beyond x max 220
        (Calibration(95.0, 200.0, 0.0, 5.5), "y"),  # beyond y max 220
        (Calibration(95.0, 10.0, 180.0, 5.5), "y"),  # rotated off the bed's front edge
    ],
)
def test_every_axis_out_of_bounds_refused(paper_layout, positions, profile, no_text, calibration, axis):
    err = refuse(paper_layout, positions, profile.with_calibration(calibration))
    assert f"printer {axis} = " in str(err)


def test_soft_limits_narrower_than_bed(paper_layout, positions, profile, no_text):
    narrow = replace(profile, soft_max_mm=replace(profile.soft_max_mm, x=110.0))
    err = refuse(paper_layout, positions, narrow)
    assert "[0, 110] mm" in str(err)


def test_press_depth_beyond_skin_thickness(paper_layout, positions, profile, no_text):
    err = refuse(paper_layout, positions, profile, PressSpec(depth_mm=5.2, repeats=1))
    assert err.field == "press.depth_mm"
    assert "beyond the skin thickness 5.5 mm minus the 0.5 mm margin (limit 5 mm)" in str(err)
    assert refuse(paper_layout, positions, profile, PressSpec(depth_mm=0.0, repeats=1)).field == "press.depth_mm"


def test_press_below_z_soft_limit(paper_layout, positions, profile, no_text):
    low = profile.with_calibration(Calibration(95.0, 95.0, 0.0, 2.0))
    err = refuse(paper_layout, positions, low)
    assert err.field == "calibration.surface_z_mm" and "z = -1.5 mm" in str(err)


def test_safe_height_above_z_soft_limit(profile):
    # a profile (or a refitted calibration) whose travel height breaks the z soft limit cannot exist
    with pytest.raises(ConfigError) as info:
        replace(profile, soft_max_mm=replace(profile.soft_max_mm, z=12.0), park_mm=replace(profile.park_mm, z=10.0))
    assert info.value.field == "motion.safe_height_mm"
    with pytest.raises(ConfigError) as info:
        profile.with_calibration(Calibration(95.0, 95.0, 0.0, 245.0))
    assert info.value.field == "motion.safe_height_mm" and "z = 245.0 mm" in str(info.value)


def test_feed_over_the_maximum(paper_layout, positions, profile, no_text):
    # PrinterProfile refuses this itself; bounds checks again in case a profile is built unchecked
    with pytest.raises(ConfigError) as info:
        replace(profile, press_feed_mm_s=9.0)
    assert info.value.field == "motion.press_feed_mm_s"
    fast = object.__new__(type(profile))
    for key, value in vars(profile).items():
        object.__setattr__(fast, key, value)
    object.__setattr__(fast, "travel_feed_mm_s", 900.0)
    err = refuse(paper_layout, positions, fast)
    assert err.field == "motion.travel_feed_mm_s" and "exceeds the printer maximum 500" in str(err)


INJECTIONS = ["x\nG28", "x\rM112", "x; M112", "a*12", "x\x00", "x\u2028G1 Z0", "x\x1bG1", "x\u0085M112"]


@pytest.mark.parametrize("name", INJECTIONS)
def test_injection_in_campaign_name_refused(paper_layout, positions, profile, no_text, name):
    err = refuse(paper_layout, positions, profile, name=name)
    assert err.field == "campaign.name" and "could inject" in str(err)


@pytest.mark.parametrize("name", INJECTIONS)
def test_injection_in_layout_and_printer_names_refused(paper_layout, positions, profile, no_text, name):
    assert refuse(replace(paper_layout, name=name), positions, profile).field == "skin.name"
    assert refuse(paper_layout, positions, replace(profile, name=name)).field == "printer.name"


@pytest.mark.parametrize("name", INJECTIONS)
def test_injection_through_the_protocol_file_refused(paper_layout, positions, profile, name):
    from neatskin.gcode.spec import build_from_spec

    data = {
        "campaign": {"name": name, "seed": 1},
        "files": {"layout": "a.toml", "printer": "b.toml"},
        "positions": {"strategy": "paper", "count": 3},
        "press": {"depth_mm": 3.5, "repeats": 1},
    }
    spec = press_spec_from_dict(data, "proto.toml")
    with pytest.raises(ConfigError) as info:
        build_from_spec(spec, layout=paper_layout, profile=profile)
    assert info.value.field == "campaign.name"


def test_safe_names_pass(paper_layout, positions, profile):
    prog = build_program(
        paper_layout, positions, PressSpec(depth_mm=3.5, repeats=1), profile, name="Run 3 (tap water, 21 C) - ok"
    )
    assert "; protocol: Run 3 (tap water, 21 C) - ok\n" in prog.text()
    # every non-comment line of the text is a command the program built
    commands = [ln for ln in prog.text().splitlines() if not ln.startswith(";")]
    assert commands == list(prog.command_lines())


@settings(max_examples=40, deadline=None)
@given(st.floats(-60, 260), st.floats(-60, 260), st.floats(-180, 180), st.floats(0, 12), st.floats(0.1, 6))
def test_either_refused_before_text_or_every_move_in_bounds(paper_layout, profile, ox, oy, rot, z, depth):
    """Property: a program that builds never moves outside the bed or soft limits; one that does not, fails
    with a ConfigError before its text exists."""
    positions = generate_positions(paper_layout, PositionSpec("paper", 8, 1))
    try:
        shifted = profile.with_calibration(Calibration(ox, oy, rot, z))
        prog = build_program(paper_layout, positions, PressSpec(depth_mm=depth, repeats=1), shifted)
    except ConfigError as exc:
        assert exc.problems
        return
    lines = parse_program(prog.text())
    assert check_moves(shifted, lines) == []
    assert check_phases(lines) == []
    assert check_commands(lines) == []  # nothing a press program must never contain
    assert depth <= paper_layout.thickness_mm - 0.5

"""Printer profiles: the paper's loads; every bad field is reported at once with file, field and fix."""

import tomllib

import pytest

from neatskin.errors import ConfigError
from neatskin.gcode.profile import load_printer_profile, printer_profile_from_dict


@pytest.fixture()
def paper_dict(protocols_dir):
    return tomllib.loads((protocols_dir / "printers" / "paper.toml").read_text())


def test_paper_profile(protocols_dir):
    p = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    assert p.firmware == "Marlin" and p.baud_rate == 115200
    assert p.planner_buffer_size == 16 and p.rx_buffer_size == 128
    assert (p.bed_x_mm, p.bed_y_mm) == (220.0, 220.0)
    assert tuple(p.max_feed_mm_s) == (500.0, 500.0, 5.0)
    assert tuple(p.max_accel_mm_s2) == (500.0, 500.0, 100.0)
    assert p.calibration.offset_x_mm == 95.0 and p.calibration.surface_z_mm == 5.5
    assert p.safe_height_mm == 10.0


def test_every_bad_field_at_once(paper_dict):
    paper_dict["bed"]["size_x_mm"] = -1
    paper_dict["max_feed"]["z_mm_s"] = "fast"
    del paper_dict["motion"]["press_feed_mm_s"]
    paper_dict["printer"]["baud_rate"] = 0
    paper_dict["calibration"]["rotation_deg"] = float("nan")
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    fields = {p.field for p in info.value.problems}
    assert fields == {
        "bed.size_x_mm",
        "max_feed.z_mm_s",
        "motion.press_feed_mm_s",
        "printer.baud_rate",
        "calibration.rotation_deg",
    }
    assert all(p.file == "printer.toml" and p.fix for p in info.value.problems)


def test_cross_field_limits(paper_dict):
    paper_dict["soft_limits"]["max_x_mm"] = 300.0  # beyond the 220 mm bed
    paper_dict["motion"]["press_feed_mm_s"] = 10.0  # above the 5 mm/s Z maximum
    paper_dict["park"]["z_mm"] = 400.0
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    assert {p.field for p in info.value.problems} == {"soft_limits.max_x_mm", "motion.press_feed_mm_s", "park.z_mm"}


def test_field_and_cross_field_problems_in_one_report(paper_dict):
    paper_dict["bed"]["size_y_mm"] = "big"
    paper_dict["motion"]["travel_feed_mm_s"] = 800.0  # above the 500 mm/s x/y maximum
    del paper_dict["soft_limits"]["min_z_mm"]  # the z checks that need it are skipped, not misreported
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    fields = [p.field for p in info.value.problems]
    assert set(fields[:2]) == {"soft_limits.min_z_mm", "bed.size_y_mm"}  # the tables' own problems first
    assert fields[2:] == ["motion.travel_feed_mm_s"]  # then the cross-field one


def test_missing_table_and_unreadable_file(paper_dict, tmp_path):
    del paper_dict["max_accel"]
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    assert info.value.problems[0].field == "max_accel"
    with pytest.raises(ConfigError, match="cannot read"):
        load_printer_profile(tmp_path / "nope.toml")
    (tmp_path / "bad.toml").write_text("[bed\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_printer_profile(tmp_path / "bad.toml")


@pytest.mark.parametrize(
    "mutate, field, fix",
    [
        (lambda d: d.update(parking=d.pop("park")), "parking", "did you mean 'park'?"),
        (lambda d: d["printer"].update(homing_tim_s=60), "printer.homing_tim_s", "did you mean 'homing_time_s'?"),
        (lambda d: d["calibration"].update(ofset_x_mm=1.0), "calibration.ofset_x_mm", "did you mean 'offset_x_mm'?"),
    ],
)
def test_misspelt_keys_and_tables_are_refused_with_a_suggestion(paper_dict, mutate, field, fix):
    # before the schema layer, a misspelt [park] silently parked at the top of the Z travel
    mutate(paper_dict)
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    assert [(p.field, p.fix) for p in info.value.problems] == [(field, fix)]


def test_park_defaults_to_the_far_corner_at_the_top_of_z(paper_dict):
    del paper_dict["park"]
    assert tuple(printer_profile_from_dict(paper_dict, "printer.toml").park_mm) == (0.0, 220.0, 250.0)


def test_extreme_values_are_refused(paper_dict):
    paper_dict["printer"]["homing_time_s"] = 1e15
    paper_dict["bed"]["size_x_mm"] = float("inf")
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    assert [p.field for p in info.value.problems] == ["printer.homing_time_s", "bed.size_x_mm"]
    assert "is above 3600" in info.value.problems[0].message


@pytest.mark.parametrize(
    "rotation, refused",
    [(1.5708, True), (-3.14159, True), (0.7854, True), (1.571, False), (90.0, False), (2.5, False), (0.0, False)],
)
def test_a_rotation_written_in_radians_is_refused(paper_dict, rotation, refused):
    paper_dict["calibration"]["rotation_deg"] = rotation
    if not refused:
        assert printer_profile_from_dict(paper_dict, "printer.toml").calibration.rotation_deg == rotation
        return
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    [problem] = info.value.problems
    degrees = round(rotation / 0.7853981633974483) * 45
    assert problem.field == "calibration.rotation_deg"
    assert problem.message == f"rotation_deg = {rotation:g} looks like {degrees:g} degrees written in radians"
    assert problem.fix.startswith(f"rotation_deg is in degrees: write {degrees:.1f} ")


def test_soft_limits_upside_down_are_one_problem_not_also_the_park(paper_dict):
    paper_dict["soft_limits"]["min_x_mm"] = 300.0
    with pytest.raises(ConfigError) as info:
        printer_profile_from_dict(paper_dict, "printer.toml")
    assert [p.field for p in info.value.problems] == ["soft_limits.max_x_mm"]


@pytest.mark.parametrize("baud", [2400, 57600, 115200, 250000, 1000000])
def test_every_marlin_baud_rate_is_accepted(paper_dict, baud):
    paper_dict["printer"]["baud_rate"] = baud
    assert printer_profile_from_dict(paper_dict, "p.toml").baud_rate == baud


@pytest.mark.parametrize(("baud", "nearest"), [(115201, 115200), (11520, 9600), (230400, 250000), (25000, 19200)])
def test_a_baud_rate_marlin_cannot_run_at_is_refused_with_the_nearest(paper_dict, baud, nearest):
    """A typo in the baud rate opens the port and reads garbage from a real printer (a pty ignores it, so a dry run
    never notices): refused when the profile says Marlin, naming the field and the nearest rate Marlin runs at."""
    paper_dict["printer"]["baud_rate"] = baud
    with pytest.raises(ConfigError) as caught:
        printer_profile_from_dict(paper_dict, "p.toml")
    (problem,) = caught.value.problems
    assert (problem.file, problem.field) == ("p.toml", "printer.baud_rate")
    assert problem.message.startswith(f"baud_rate = {baud} is not a speed Marlin runs at")
    assert problem.fix.endswith(f"(nearest: {nearest})")
    paper_dict["printer"]["firmware"] = "Repetier"  # another firmware's rates are its own
    assert printer_profile_from_dict(paper_dict, "p.toml").baud_rate == baud

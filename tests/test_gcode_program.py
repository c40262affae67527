"""Press programs: structure, markers, holds, order, determinism and the emit -> parse round trip."""

from collections import Counter

import numpy as np
import pytest

from neatskin.gcode.calibration import Calibration
from neatskin.gcode.parse import parse_program
from neatskin.gcode.positions import PositionSpec, generate_positions
from neatskin.gcode.profile import load_printer_profile
from neatskin.gcode.program import PressSpec, build_program
from neatskin.gcode.spec import build_from_protocol


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


@pytest.fixture(scope="module")
def positions(paper_layout):
    return generate_positions(paper_layout, PositionSpec("paper", 10, 11))


def build(layout, positions, profile, **press):
    kwargs = dict(depth_mm=3.5, repeats=3, order="position", hold_s=0.5)
    kwargs.update(press)
    hold = kwargs.pop("hold_in_gcode", False)
    return build_program(layout, positions, PressSpec(**kwargs), profile, name="t", seed=4, hold_in_gcode=hold)


def test_same_protocol_gives_byte_identical_gcode(protocols_dir):
    a, _, _ = build_from_protocol(protocols_dir / "paper.toml")
    b, _, _ = build_from_protocol(protocols_dir / "paper.toml")
    assert a.text().encode() == b.text().encode()
    assert len(a.presses) == 2800 and len(a.positions) == 100
    assert "; seed: 2019" in a.text() and "; protocol: paper" in a.text()


def test_press_block_phases_exact_lines(paper_layout, positions, profile):
    prog = build(paper_layout, positions, profile, hold_in_gcode=True)
    block = prog.presses[4]
    assert (block.press_id, block.position_id, block.repeat) == (4, 1, 1)
    px, py = (f"{v:.3f}".rstrip("0").rstrip(".") for v in (positions.x_mm[1] + 95.0, positions.y_mm[1] + 95.0))
    assert [p.name for p in block.phases] == ["travel", "descend", "press", "lift"]
    assert [p.acquire for p in block.phases] == ["baseline", None, "pressed", None]
    assert block.phase("travel").lines == (
        "M118 E1 NS press=4 phase=travel",
        "G0 Z15.5 F300",
        f"G0 X{px} Y{py} F6000",
        "M400",
    )
    assert block.phase("descend").lines == ("M118 E1 NS press=4 phase=descend", "G1 Z5.5 F300", "M400")
    assert block.phase("press").lines == ("M118 E1 NS press=4 phase=press", "G1 Z2 F120", "G4 P500", "M400")
    assert block.phase("lift").lines == ("M118 E1 NS press=4 phase=lift", "G0 Z15.5 F300", "M400")
    assert all(p.lines[-1] == "M400" for p in block.phases)


def test_runner_program_has_no_hold(paper_layout, positions, profile):
    prog = build(paper_layout, positions, profile, hold_in_gcode=False)
    assert prog.presses[0].phase("press").lines == ("M118 E1 NS press=0 phase=press", "G1 Z2 F120", "M400")
    assert not any(line.startswith("G4") for line in prog.command_lines())


def test_preamble_and_postamble(paper_layout, positions, profile):
    prog = build(paper_layout, positions, profile)
    # Z rises by the surface (5.5) + the safe height (10) before homing (G28's R word): a probe left in the skin
    # by a crash clears it and the fittings before X and Y home (tests/test_preamble_raise.py on the real firmware)
    assert prog.preamble == ("G21", "G90", "M211 S1", "G28 R15.5", "M400")
    assert prog.postamble == ("G0 Z15.5 F300", "G0 X0 Y200 F6000", "G0 Z60 F300", "M400", "M118 E1 NS program=done")


def test_round_trip_emit_parse_same_moves(paper_layout, profile):
    positions = generate_positions(paper_layout, PositionSpec("paper", 25, 3))
    rotated = profile.with_calibration(Calibration(110.0, 60.0, 30.0, 7.25))
    prog = build_program(
        paper_layout, positions, PressSpec(depth_mm=3.5, repeats=2, hold_s=0.25), rotated, seed=1, hold_in_gcode=True
    )
    lines = parse_program(prog.text())
    xy_moves = [(ln.params["X"], ln.params["Y"]) for ln in lines if ln.code == "G0" and "X" in ln.params]
    press_z = [ln.params["Z"] for ln in lines if ln.code == "G1" and ln.params.get("F") == 120.0]
    assert len(xy_moves) == len(prog.presses) + 1  # + park
    assert len(press_z) == len(prog.presses)
    expected = np.array([b.printer_xyz_mm[:2] for b in prog.presses])
    assert np.abs(np.array(xy_moves[:-1]) - expected).max() <= 5e-4
    assert press_z == [3.75] * len(prog.presses)
    # back to the sensor frame: the commanded positions are the generated ones (to the 1 um format)
    sx, sy = rotated.calibration.to_sensor(*np.array(xy_moves[:-1]).T)
    want = np.array([(b.x_mm, b.y_mm) for b in prog.presses])
    assert np.abs(np.column_stack([sx, sy]) - want).max() <= 1e-3
    markers = [ln.text for ln in lines if ln.code == "M118"]
    assert markers[:4] == [f"NS press=0 phase={p}" for p in ("travel", "descend", "press", "lift")]
    assert len(markers) == 4 * len(prog.presses) + 1
    assert sum(1 for ln in lines if ln.code == "G4" and ln.params == {"P": 250.0}) == len(prog.presses)


def test_order_position_groups_repeats(paper_layout, positions, profile):
    prog = build(paper_layout, positions, profile, repeats=3)
    assert [(b.position_id, b.repeat) for b in prog.presses[:6]] == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    assert [b.press_id for b in prog.presses] == list(range(30))


def test_order_shuffled_is_seeded_and_complete(paper_layout, positions, profile):
    a = build(paper_layout, positions, profile, repeats=4, order="shuffled")
    b = build(paper_layout, positions, profile, repeats=4, order="shuffled")
    pairs = [(blk.position_id, blk.repeat) for blk in a.presses]
    assert pairs == [(blk.position_id, blk.repeat) for blk in b.presses]
    assert sorted(pairs) == [(p, r) for p in range(10) for r in range(4)]
    assert Counter(p for p, _ in pairs) == {p: 4 for p in range(10)}
    # drift must not line up with position: the first 10 presses are not all one position
    assert len({p for p, _ in pairs[:10]}) > 3
    c = build_program(paper_layout, positions, PressSpec(depth_mm=3.5, repeats=4, order="shuffled"), profile, seed=5)
    assert [(blk.position_id, blk.repeat) for blk in c.presses] != pairs


def test_travel_ordering_shortens_the_route(paper_layout, profile):
    positions = generate_positions(paper_layout, PositionSpec("paper", 100, 2019))
    plain = build_program(paper_layout, positions, PressSpec(depth_mm=3.5, repeats=1), profile)
    ordered = build_program(paper_layout, positions, PressSpec(depth_mm=3.5, repeats=1, travel_ordering=True), profile)
    assert plain.route_unordered_mm is None
    assert ordered.route_unordered_mm == pytest.approx(plain.route_mm)
    assert ordered.route_mm < 0.4 * plain.route_mm  # paper seed: 1783 mm in generated order, 251 mm ordered
    assert sorted(b.position_id for b in ordered.presses) == list(range(100))
    assert "; travel ordering: route" in ordered.text()


@pytest.mark.parametrize("first", [0, 7, 29])
def test_sideways_moves_only_at_safe_height_even_when_resuming(paper_layout, positions, profile, first):
    """The probe never moves sideways below the safe height (it would drag over the skin and its fittings),
    also when a resumed campaign sends the preamble and then starts at press `first`."""
    prog = build(paper_layout, positions, profile, repeats=3, order="shuffled")
    lines = (
        list(prog.preamble)
        + [ln for b in prog.presses[first:] for ph in b.phases for ln in ph.lines]
        + list(prog.postamble)
    )
    safe_z = profile.calibration.surface_z_mm + profile.safe_height_mm
    z = None  # unknown until homed
    sideways = 0
    for parsed in parse_program("\n".join(lines)):
        if parsed.code == "G28":
            z = 0.0
        elif parsed.code in ("G0", "G1"):
            if "X" in parsed.params or "Y" in parsed.params:
                assert z is not None and z >= safe_z, parsed.raw
                sideways += 1
            z = parsed.params.get("Z", z)
    assert sideways == len(prog.presses) - first + 1

"""G-code line parsing: commands, parameters, comments, Marlin host framing and checksums."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from neatskin.gcode.parse import GcodeSyntaxError, checksum, frame_line, parse_line, parse_program


def test_move_with_comment():
    line = parse_line("G1 X10.5 Y-2 Z.25 F3000 ; to the target")
    assert line.code == "G1"
    assert line.params == {"X": 10.5, "Y": -2.0, "Z": 0.25, "F": 3000.0}
    assert line.comment == "to the target"
    assert line.line_number is None and line.checksum is None and line.checksum_ok is None


def test_parameters_without_spaces_and_lower_case():
    assert parse_line("g1x10y20").params == {"X": 10.0, "Y": 20.0}
    assert parse_line("G1X10Y20").code == "G1"


def test_blank_and_comment_only_lines_are_none():
    assert parse_line("") is None
    assert parse_line("   \r\n") is None
    assert parse_line("; just a comment") is None


def test_flags_without_values_and_tool_and_subcode():
    assert parse_line("G28 X Y").params == {"X": "", "Y": ""}
    assert parse_line("T0").code == "T0"
    assert parse_line("G29.1").code == "G29.1"
    assert parse_line("G01 X1").code == "G1"


def test_m118_keeps_text_and_flags():
    line = parse_line("M118 E1 NS press=17 phase=press")
    assert line.code == "M118"
    assert line.params == {"E": 1.0, "text": "NS press=17 phase=press"}
    assert line.text == "NS press=17 phase=press"


def test_m117_text_is_a_string_param():
    line = parse_line("M117 X10 is not a move")
    assert line.params == {"text": "X10 is not a move"}


def test_checksum_is_xor_of_bytes_before_star():
    # N1 G28 -> bytes N,1,space,G,2,8
    expected = 0
    for b in b"N1 G28":
        expected ^= b
    assert checksum("N1 G28") == expected == checksum("N1 G28*99")
    assert frame_line("G28", 1) == f"N1 G28*{expected}"


def test_host_framing_returns_line_number_and_checksum():
    framed = frame_line("G1 X1", 123)
    line = parse_line(framed)
    assert line.code == "G1" and line.params == {"X": 1.0}
    assert line.line_number == 123
    assert line.checksum == checksum("N123 G1 X1")
    assert line.checksum_ok is True
    bad = parse_line("N123 G1 X1*45")
    assert bad.line_number == 123 and bad.checksum == 45
    assert bad.checksum_ok is (checksum("N123 G1 X1") == 45)


def test_m110_keeps_its_n_parameter():
    line = parse_line(frame_line("M110 N0", 0))
    assert line.code == "M110" and line.params == {"N": 0.0} and line.line_number == 0


@pytest.mark.parametrize("text", ["hello", "G1 X1.2.3", "N1 G1 X1*abc", "N5*12", "X10 Y10", "G1 X1 ?"])
def test_syntax_errors_name_the_line(text):
    with pytest.raises(GcodeSyntaxError) as info:
        parse_line(text, source="f.gcode", line_no=7)
    assert info.value.file == "f.gcode" and info.value.field == "line 7"


def test_parse_program_reports_every_bad_line():
    with pytest.raises(GcodeSyntaxError) as info:
        parse_program("G28\nfoo\nG1 X1\nbar\n", source="p.gcode")
    assert [p.field for p in info.value.problems] == ["line 2", "line 4"]
    assert [line.code for line in parse_program("G28\n; c\n\nG1 X1\n")] == ["G28", "G1"]


@given(st.integers(0, 10**6), st.floats(-1000, 1000, allow_nan=False).map(lambda v: round(v, 3)))
def test_framed_moves_round_trip(n, x):
    line = parse_line(frame_line(f"G1 X{x}", n))
    assert line.line_number == n and line.params["X"] == x and line.checksum_ok

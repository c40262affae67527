"""`gcode check` refuses what the real firmware would not run as written: lower-case letters and overlong commands.

The premise is the real firmware's (../shared/marlin, native stock build; skipped without it): `G1 X5 y7` moves
X only, `g1 x10` is an unknown command, and a command longer than MAX_COMMAND_CHARS loses its tail (numbered, it
fails its checksum on every resend). The simulated printer and this toolkit's parser read all of them as moves.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import serial

from neatskin.cli import main
from neatskin.gcode.bounds import MAX_COMMAND_CHARS, check_commands
from neatskin.gcode.parse import frame_line, parse_numbered
from neatskin.sim.realmarlin import PLAIN, FirmwareRelay, find_marlin_dir

REPO = Path(__file__).resolve().parent.parent
MARLIN = find_marlin_dir(REPO)


def _padded(length: int) -> str:
    """A G1 of exactly `length` characters (spaces inside, as a hand-edited file has them), Z last."""
    head, tail = "G1 X30 Y30 F3000", " Z5"
    return head + " " * (length - len(head) - len(tail)) + tail


def _problems(text: str) -> list[tuple[str, str]]:
    numbered = parse_numbered(text, "p.gcode")
    found = check_commands([line for _, line in numbered], "p.gcode", [n for n, _ in numbered])
    return [(p.field, p.message) for p in found]


def test_lower_case_commands_and_parameters_are_refused_upper_case_text_and_comments_pass():
    text = "\n".join(
        [
            "G21",
            "g1 x10 y10",  # line 2: Marlin: Unknown command
            "G1 X5 y7",  # line 3: Marlin moves X only
            "G1 X1e1 Y2 F3000 ; any case in a comment",  # an exponent's e is part of the number
            "M118 E1 neatskin-probe 3",  # a text command's text
            "M117 press ok",
            "N7 G1 X1 Y1*99",  # framing is the host's, not a parameter
        ]
    )
    found = _problems(text)
    assert [field for field, _ in found] == ["line 2", "line 3"]
    assert all("lower-case letter" in message for _, message in found)


def test_a_command_longer_than_marlin_keeps_is_refused_to_the_character():
    assert _problems(_padded(MAX_COMMAND_CHARS)) == []
    found = _problems(_padded(MAX_COMMAND_CHARS + 1))
    assert [field for field, _ in found] == ["line 1"]
    assert f"{MAX_COMMAND_CHARS + 1} characters" in found[0][1]
    # the budget: the longest framed line the host can send stays inside Marlin's 95 characters
    assert len(frame_line(_padded(MAX_COMMAND_CHARS), 9_999_999)) <= 95


def test_gcode_check_exits_1_naming_the_line_and_the_fix(tmp_path, capsys):
    program = tmp_path / "p.gcode"
    program.write_text(f"G28\nG1 X5 y7 F3000\n{_padded(MAX_COMMAND_CHARS + 5)}\nM400\n")
    assert main(["gcode", "check", str(program)]) == 1
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("neatskin: error:")]
    assert len(errors) == 2
    assert (
        f"{program}: [line 2]:" in errors[0]
        and "(fix: write the command and its parameter letters in upper case ('G1 X5 Y7 F3000'))" in errors[0]
    )
    assert f"{program}: [line 3]:" in errors[1] and f"at most {MAX_COMMAND_CHARS} characters" in errors[1]


def _exchange(port: serial.Serial, line: str, wait_s: float = 5.0) -> list[str]:
    """Send one line, return the reply lines up to and including its `ok` (busy keep-alives left out)."""
    port.write(line.encode("ascii") + b"\n")
    got: list[str] = []
    buffer = b""
    end = time.monotonic() + wait_s
    while time.monotonic() < end:
        buffer += port.read(4096)
        while b"\n" in buffer:
            raw, buffer = buffer.split(b"\n", 1)
            text = raw.decode("ascii", "replace").strip()
            if text and not text.startswith("busy:"):
                got.append(text)
            if text.startswith("ok"):
                return got
    raise AssertionError(f"no ok for {line!r}; got {got}")


@pytest.mark.timeout(60)
@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
def test_the_real_firmware_ignores_a_lower_case_parameter_and_a_long_commands_tail():
    assert MARLIN is not None
    with FirmwareRelay(MARLIN / PLAIN) as relay:
        port = serial.Serial(relay.path, 115200, timeout=0.05)
        try:
            _exchange(port, "G92 X0 Y0 Z0")
            assert _exchange(port, "g1 x10 y10") == ['echo:Unknown command: "g1 x10 y10"', "ok"]
            _exchange(port, "G1 X5 y7 F3000")
            _exchange(port, "M400")
            assert _exchange(port, "M114")[0].startswith("X:5.00 Y:0.00 Z:0.00")  # y7 ignored
            _exchange(port, _padded(MAX_COMMAND_CHARS + 20))  # unnumbered: the tail (Z5) is lost
            _exchange(port, "M400")
            assert _exchange(port, "M114")[0].startswith("X:30.00 Y:30.00 Z:0.00")
            _exchange(port, "M110 N0")
            long_numbered = frame_line(_padded(MAX_COMMAND_CHARS + 20), 1)
            assert _exchange(port, long_numbered)[0] == "Error:No Checksum with line number, Last Line: 0"
            assert _exchange(port, frame_line(_padded(MAX_COMMAND_CHARS), 1)) == ["ok"]
        finally:
            port.close()

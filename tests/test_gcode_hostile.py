"""`gcode check` and `gcode generate` under hostile input: every outcome is a clear error or a refusal, never a traceback."""

from __future__ import annotations

import os

import pytest

from neatskin.cli import main
from neatskin.errors import ConfigError
from neatskin.gcode.emit import write_text_atomic
from neatskin.gcode.parse import GcodeSyntaxError, parse_line, read_program_file


@pytest.fixture
def paper_profile(protocols_dir):
    return str(protocols_dir / "printers" / "paper.toml")


def test_check_refuses_eeprom_heaters_and_m112_one_line_each(tmp_path, capsys, paper_profile):
    program = tmp_path / "p.gcode"
    program.write_text("G28\nM500\n; a comment\nM104 S300\nG1 X10 F3000\nM112\nM303\nM502\nM140 S60\nM999\nM190\n")
    assert main(["gcode", "check", str(program), "--profile", paper_profile]) == 1
    refused = [line for line in capsys.readouterr().err.splitlines() if line.startswith("neatskin: error:")]
    assert [line.split("[", 1)[1].split("]", 1)[0] for line in refused] == [
        "line 2",
        "line 4",
        "line 6",
        "line 7",
        "line 8",
        "line 9",
        "line 10",
        "line 11",
    ]
    assert "M500 writes the settings to the EEPROM" in refused[0]
    assert "M104 heats the hotend" in refused[1] and "M112 is an emergency stop" in refused[2]
    assert "M999 is not a command a press program uses" in refused[6]
    # the same refusals without a profile
    assert main(["gcode", "check", str(program)]) == 1
    assert capsys.readouterr().err.count("neatskin: error:") == 8


def test_a_generated_program_passes_the_command_check(protocols_dir, tmp_path, capsys, paper_profile):
    out = tmp_path / "smoke.gcode"
    assert main(["gcode", "generate", str(protocols_dir / "smoke.toml"), "-o", str(out)]) == 0
    assert main(["gcode", "check", str(out), "--profile", paper_profile]) == 0
    assert "neatskin: error" not in capsys.readouterr().err


@pytest.mark.parametrize("word", ["X1e999", "X-1e400", "Xnan", "XNaN", "Xinf", "X-inf", "Xinfinity"])
def test_numbers_must_be_finite(word):
    with pytest.raises(GcodeSyntaxError, match="is not a finite number"):
        parse_line(f"G1 {word} Y2")


@pytest.mark.parametrize("word", ["X1e300", "X99999999999", "F-3000000000", "P2147483649"])
def test_numbers_beyond_marlins_range_are_refused(word):
    with pytest.raises(GcodeSyntaxError, match="is beyond"):
        parse_line(f"G1 {word}")
    assert parse_line("G1 X2147483648").params == {"X": 2147483648.0}  # 2^31 itself is in range


def test_check_of_huge_coordinates_is_a_clear_error(tmp_path, capsys, paper_profile):
    program = tmp_path / "p.gcode"
    program.write_text("G28\nG1 X1e300 Y1e300\nG4 P1e300\n")
    assert main(["gcode", "check", str(program), "--profile", paper_profile]) == 1
    err = capsys.readouterr().err
    assert "[line 2]: 'X1e300' is beyond" in err and "[line 3]: 'P1e300' is beyond" in err


@pytest.mark.parametrize("profile", [False, True])
def test_check_of_an_infinite_or_nan_coordinate_is_a_clear_error(tmp_path, capsys, paper_profile, profile):
    program = tmp_path / "p.gcode"
    program.write_text("G28\nG1 X1e999\nG1 Xnan\n")
    argv = ["gcode", "check", str(program)] + (["--profile", paper_profile] if profile else [])
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "[line 2]: 'X1e999' is not a finite number" in err and "[line 3]: 'Xnan' is not a finite number" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"PAR1\x15\x04\x15\x10\x00\x00PAR1", "holds NUL bytes (the first at byte 8)"),
        (b"G28\nG1 X1 ; caf\xe9\n", "is not UTF-8 text (byte 0xe9 at offset 15)"),
    ],
)
def test_check_of_a_binary_or_non_utf8_file_is_one_config_error(tmp_path, capsys, content, expected):
    path = tmp_path / "data.parquet"
    path.write_bytes(content)
    assert main(["gcode", "check", str(path)]) == 1
    err = capsys.readouterr().err
    assert expected in err and str(path) in err and "UnicodeDecodeError" not in err


def test_read_is_capped(tmp_path):
    path = tmp_path / "big.gcode"
    path.write_bytes(b"G4 P1\n" * 200)
    with pytest.raises(ConfigError, match="larger than 0 MiB"):
        read_program_file(path, max_bytes=1000)
    assert read_program_file(path, max_bytes=1200) == "G4 P1\n" * 200
    # a device is refused before a byte is read (a serial port named by mistake would block the read)
    with pytest.raises(ConfigError) as info:
        read_program_file("/dev/zero", max_bytes=1024 * 1024)
    assert str(info.value) == (
        "/dev/zero: G-code file is not a regular file (a device, folder or pipe) (fix: name a G-code file; "
        "check the path; give the .gcode file written by `neatskin gcode generate`)"
    )


def test_check_of_a_folder_is_a_clear_error(tmp_path, capsys):
    assert main(["gcode", "check", str(tmp_path)]) == 1
    assert "cannot read G-code file: Is a directory" in capsys.readouterr().err


def _smoke_copy(protocols_dir, tmp_path, name: str):
    text = (protocols_dir / "smoke.toml").read_text().replace('name = "smoke"', f'name = "{name}"')
    text = text.replace('"skins/', f'"{protocols_dir}/skins/').replace('"printers/', f'"{protocols_dir}/printers/')
    proto = tmp_path / "proto.toml"
    proto.write_text(text, encoding="utf-8")
    return proto


def test_generate_with_a_non_ascii_name_is_clear_and_leaves_nothing(protocols_dir, tmp_path, capsys):
    proto = _smoke_copy(protocols_dir, tmp_path, "Kampagne Üben")
    out = tmp_path / "out" / "p.gcode"
    assert main(["gcode", "generate", str(proto), "-o", str(out)]) == 3
    err = capsys.readouterr().err
    # refused by the protocol schema, before emission (which refuses it too: see test_emit_refuses_a_non_ascii_name)
    assert "campaign.name" in err and "non-ASCII" in err and "UnicodeEncodeError" not in err
    assert not out.exists() and not (tmp_path / "out" / "p.gcode.tmp").exists()


def test_a_full_disk_leaves_the_old_file_and_no_temp_file(tmp_path, monkeypatch):
    import errno

    import neatskin.gcode.emit as emit

    out = tmp_path / "p.gcode"
    out.write_text("old\n")

    def full(*_args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(emit.os, "replace", full)
    with pytest.raises(ConfigError, match="cannot write .*No space left on device") as info:
        write_text_atomic(out, "G28\n", "ascii", "--output")
    assert info.value.field == "--output"
    assert sorted(os.listdir(tmp_path)) == ["p.gcode"] and out.read_text() == "old\n"


def test_write_text_atomic_leaves_no_temp_file_on_an_encoding_or_disk_failure(tmp_path):
    out = tmp_path / "p.gcode"
    with pytest.raises(ConfigError, match="cannot write 'é' \\(U\\+00E9\\) as ascii"):
        write_text_atomic(out, "; café\n", "ascii", "--output")
    assert sorted(os.listdir(tmp_path)) == []
    out.write_text("old\n")
    os.chmod(tmp_path, 0o500)
    try:
        if os.access(tmp_path, os.W_OK):
            pytest.skip("running as a user who may write anywhere")
        with pytest.raises(ConfigError, match="cannot write .*Permission denied"):
            write_text_atomic(out, "G28\n", "ascii", "--output")
    finally:
        os.chmod(tmp_path, 0o700)
    assert sorted(os.listdir(tmp_path)) == ["p.gcode"] and out.read_text() == "old\n"


@pytest.mark.parametrize("where", ["folder", "under_a_file"])
def test_generate_to_a_folder_or_below_a_file_is_one_clear_error(protocols_dir, tmp_path, capsys, where):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = tmp_path if where == "folder" else blocker / "p.gcode"
    assert main(["gcode", "generate", str(protocols_dir / "smoke.toml"), "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert "[--out]" in err and (
        "is a folder, not a file" in err if where == "folder" else "is a file, not a folder" in err
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_emit_refuses_a_non_ascii_name():
    from neatskin.errors import ConfigError
    from neatskin.gcode.emit import safe_text

    with pytest.raises(ConfigError) as info:
        safe_text("Kampagne Üben", "campaign.name", "proto.toml")
    assert info.value.problems[0].field == "campaign.name"
    assert "non-ASCII character 'Ü' (U+00DC)" in str(info.value)


@pytest.mark.parametrize("text", ["", "; only a comment\n\n", "\n\n   \n"])
def test_check_of_a_program_without_commands_is_one_error(tmp_path, capsys, paper_profile, text):
    program = tmp_path / "empty.gcode"
    program.write_text(text)
    assert main(["gcode", "check", str(program), "--profile", paper_profile]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"neatskin: error: {program}: holds no G-code command (empty, or comments only): not a press program "
        "(fix: give the .gcode file written by `neatskin gcode generate`)\n"
    )


def test_a_byte_order_mark_is_read_past(tmp_path):
    program = tmp_path / "bom.gcode"
    program.write_bytes(b"\xef\xbb\xbf; a comment\r\nG28\r\n")
    assert read_program_file(program) == "; a comment\r\nG28\r\n"


@pytest.mark.parametrize("profile", ["missing.toml", "wiring"])
def test_a_bad_profile_is_one_error_before_anything_is_printed(tmp_path, capsys, protocols_dir, profile):
    program = tmp_path / "p.gcode"
    program.write_text("G28\n")
    path = protocols_dir / "wiring" / "paper.toml" if profile == "wiring" else tmp_path / profile
    assert main(["gcode", "check", str(program), "--profile", str(path)]) == 3
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1 and str(path) in captured.err

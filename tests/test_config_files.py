"""Reading TOML files: hostile paths and contents are one ConfigError naming the file and the fix."""

import pytest

from neatskin.errors import ConfigError
from neatskin.tomlfile import MAX_TOML_BYTES, read_text_capped, read_toml, resolve_path


def test_non_utf8_file(tmp_path):
    path = tmp_path / "p.toml"
    path.write_bytes(b'[campaign]\nname = "caf\xe9"\n')
    with pytest.raises(ConfigError) as info:
        read_toml(path, "protocol file")
    assert info.value.file == str(path) and "protocol file is not UTF-8 text (byte 0xe9 at offset 22)" in str(
        info.value
    )
    assert "save the file as UTF-8" in info.value.problems[0].fix


def test_binary_file_is_not_utf8(tmp_path):
    path = tmp_path / "data.parquet"
    path.write_bytes(b"PAR1\x15\x04\x15\x80\xff\x00")
    with pytest.raises(ConfigError, match="not UTF-8"):
        read_toml(path, "protocol file")


def test_device_is_refused_before_reading():
    with pytest.raises(ConfigError) as info:
        read_toml("/dev/zero", "printer profile")
    assert info.value.file == "/dev/zero" and "not a regular file" in str(info.value)


def test_folder_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="not a regular file|Is a directory"):
        read_toml(tmp_path, "layout file")


def test_oversized_file_is_refused(tmp_path):
    path = tmp_path / "big.toml"
    path.write_bytes(b"#" * (MAX_TOML_BYTES + 1))
    with pytest.raises(ConfigError, match="larger than 4 MiB"):
        read_toml(path, "layout file")


def test_file_name_too_long(tmp_path):
    path = tmp_path / ("x" * 5000 + ".toml")
    assert resolve_path(path) == path
    with pytest.raises(ConfigError) as info:
        read_toml(path, "protocol file")
    assert "cannot read protocol file: File name too long" in str(info.value)
    assert len(info.value.file) < 400 and "(5" in info.value.file  # shortened, with its length


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read wiring file: No such file"):
        read_toml(tmp_path / "nope.toml", "wiring file")


def test_gcode_generate_names_the_protocol_field_of_an_unreadable_printer(tmp_path, capsys):
    from conftest import PROTOCOLS

    from neatskin.cli import main

    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace('"printers/paper.toml"', '"/dev/zero"').replace('"skins/', f'"{PROTOCOLS}/skins/')
    protocol = tmp_path / "p.toml"
    protocol.write_text(text)
    out = tmp_path / "p.gcode"
    assert main(["gcode", "generate", str(protocol), "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"neatskin: error: {protocol}: [files.printer]: printer profile is not a regular file")
    assert not out.exists() and not (tmp_path / "p.gcode.tmp").exists()


def test_the_one_capped_reader_refuses_nul_bytes_only_when_asked(tmp_path):
    path = tmp_path / "data.parquet"
    path.write_bytes(b"PAR1\x15\x04\x15\x10\x00\x00PAR1")
    assert read_text_capped(path, "notes", "name the notes file") == "PAR1\x15\x04\x15\x10\x00\x00PAR1"
    with pytest.raises(ConfigError) as info:
        read_text_capped(path, "G-code file", "give a .gcode file", kind="G-code file", refuse_nul=True)
    assert (info.value.file, info.value.field) == (str(path), "<encoding>")
    assert str(info.value) == (
        f"{path}: [<encoding>]: G-code file holds NUL bytes (the first at byte 8): a binary file (parquet, image, "
        "...), not a G-code file (fix: name the right file; give a .gcode file)"
    )


def test_the_one_capped_reader_names_the_kind_of_file_in_every_message(tmp_path):
    big = tmp_path / "big.gcode"
    big.write_bytes(b"G4 P1\n" * 200)
    with pytest.raises(ConfigError) as info:
        read_text_capped(big, "G-code file", "give a .gcode file", 1000, kind="G-code file")
    assert str(info.value) == (
        f"{big}: G-code file is larger than 0 MiB: not a G-code file of this toolkit "
        "(fix: name the right file; give a .gcode file)"
    )
    latin = tmp_path / "latin.gcode"
    latin.write_bytes(b"\xef\xbb\xbfG28 ; caf\xe9\n")
    with pytest.raises(ConfigError) as info:
        read_text_capped(latin, "G-code file", "give a .gcode file", kind="G-code file")
    assert info.value.problems[0].message == "G-code file is not UTF-8 text (byte 0xe9 at offset 12)"
    assert info.value.problems[0].fix == (
        "save the file as UTF-8 (G-code files are UTF-8 text), or name the right file; give a .gcode file"
    )
    latin.write_bytes(b"\xef\xbb\xbfG28 ; cafe\n")
    assert read_text_capped(latin, "G-code file", "give a .gcode file", kind="G-code file") == "G28 ; cafe\n"

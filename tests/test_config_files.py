"""Reading TOML files: hostile paths and contents are one ConfigError naming the file and the fix."""

import pytest

from neatskin.errors import ConfigError
from neatskin.tomlfile import MAX_TOML_BYTES, read_toml, resolve_path


def test_non_utf8_file(tmp_path):
    path = tmp_path / "p.toml"
    path.write_bytes(b'[campaign]\nname = "caf\xe9"\n')
    with pytest.raises(ConfigError) as info:
        read_toml(path, "protocol file")
    assert info.value.file == str(path) and "not UTF-8 text (byte 22: b'\\xe9')" in str(info.value)
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
    assert main(["gcode", "generate", str(protocol), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"neatskin: error: {protocol}: [files.printer]: printer profile is not a regular file")
    assert not out.exists() and not (tmp_path / "p.gcode.tmp").exists()

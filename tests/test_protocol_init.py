"""`neatskin protocol init DIR`: a whole template (regular files, no links), accepted by `campaign check`, that
reads nothing outside DIR."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from neatskin.cli import main
from neatskin.config.template import init_protocol
from neatskin.errors import ConfigError


def _files(folder: Path) -> dict[str, bool]:
    """Every entry under the folder: relative path -> is it a regular file (not a link)."""
    return {
        str(p.relative_to(folder)): p.is_file() and not p.is_symlink()
        for p in sorted(folder.rglob("*"))
        if not p.is_dir() or p.is_symlink()
    }


def test_init_copies_the_protocol_and_its_hardware_files_and_campaign_check_accepts_it(tmp_path, capsys):
    out = tmp_path / "mine"
    assert main(["protocol", "init", str(out)]) == 0
    assert _files(out) == {
        "paper.toml": True,
        "printers/paper.toml": True,
        "skins/paper.toml": True,
        "wiring/paper.toml": True,
    }
    capsys.readouterr()
    assert main(["campaign", "check", str(out / "paper.toml")]) == 0
    assert "2800 presses" in capsys.readouterr().out


def test_the_copy_is_what_campaign_check_reads(tmp_path, capsys):
    """Negative control: break the copied skin; check now fails naming the copy, so it read the copy."""
    out = tmp_path / "mine"
    init_protocol(out, "smoke")
    skin = out / "skins" / "paper.toml"
    skin.write_text(skin.read_text().replace("[[junctions]]", "[[junctionz]]", 1))
    capsys.readouterr()
    assert (
        main(["campaign", "check", str(out / "smoke.toml")]) == 1
    )  # the check failed (neatskin.errors.ExitCode.CHECK_FAILED)
    assert str(skin) in capsys.readouterr().err


def test_a_file_outside_the_protocol_folder_is_copied_in_and_its_reference_rewritten(tmp_path, capsys):
    src = tmp_path / "src"
    init_protocol(src / "lab", "smoke")
    (src / "shared").mkdir()
    os.replace(src / "lab" / "printers" / "paper.toml", src / "shared" / "printer.toml")
    proto = src / "lab" / "smoke.toml"
    proto.write_text(proto.read_text().replace('"printers/paper.toml"', '"../shared/printer.toml"'))
    written = init_protocol(tmp_path / "copy", str(proto))
    assert tmp_path / "copy" / "external" / "printer.toml" in written
    assert 'printer = "external/printer.toml"' in (tmp_path / "copy" / "smoke.toml").read_text()
    capsys.readouterr()
    assert main(["campaign", "check", str(tmp_path / "copy" / "smoke.toml")]) == 0


def test_init_refuses_a_folder_with_files_and_an_unknown_protocol(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.toml").write_text("x = 1")
    with pytest.raises(ConfigError, match="not empty"):
        init_protocol(tmp_path / "full")
    assert (tmp_path / "full" / "keep.toml").read_text() == "x = 1"
    with pytest.raises(ConfigError, match="packaged protocols: paper, smoke"):
        init_protocol(tmp_path / "new", "nope")

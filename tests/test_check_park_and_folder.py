"""`campaign check`: a [park] z_mm below the travel height is one warning (the program parks at the travel height),
and a campaign folder is checked with the protocol and files it ran with (its inputs/)."""

from __future__ import annotations

from pathlib import Path

from neatskin.cli import main
from neatskin.errors import ExitCode
from neatskin.gcode.program import low_park_warning, park_z_mm
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"


def protocol_with(tmp_path: Path, park_z: str | None, count: int = 6) -> Path:
    printer = (PROTOCOLS / "printers" / "paper.toml").read_text()
    if park_z is not None:
        assert "\nz_mm = 60.0" in printer
        printer = printer.replace("\nz_mm = 60.0", f"\nz_mm = {park_z}")
    (tmp_path / "printer.toml").write_text(printer)
    text = (PROTOCOLS / "smoke.toml").read_text().replace("count = 6", f"count = {count}")
    text = text.replace('"printers/paper.toml"', f'"{tmp_path / "printer.toml"}"')
    for sub in ("skins/", "wiring/"):
        text = text.replace(f'"{sub}', f'"{PROTOCOLS}/{sub}')
    path = tmp_path / "p.toml"
    path.write_text(text)
    return path


def test_a_park_below_the_travel_height_is_one_warning_and_parks_at_the_travel_height(tmp_path, capsys):
    protocol = load_protocol(protocol_with(tmp_path, "8.0"))
    assert park_z_mm(protocol.printer) == 15.5  # surface 5.5 + safe height 10
    assert build_plan(protocol).program.postamble[2] == "G0 Z15.5 F300"
    assert main(["campaign", "check", str(tmp_path / "p.toml")]) == ExitCode.OK
    warnings = [line for line in capsys.readouterr().out.splitlines() if "[park]" in line]
    assert warnings == [
        f"  warning: {tmp_path / 'printer.toml'}: [park] z_mm = 8 is below the travel height 15.5 "
        "(calibration.surface_z_mm 5.5 + motion.safe_height_mm 10): the probe parks at Z 15.5"
    ]


def test_a_park_at_or_above_the_travel_height_says_nothing(tmp_path, capsys):
    for z in ("15.5", None):  # at the floor; the paper profile's 60
        protocol = load_protocol(protocol_with(tmp_path, z))
        assert low_park_warning(protocol.printer) is None
        assert build_plan(protocol).program.postamble[2] == f"G0 Z{'15.5' if z else '60'} F300"
    assert main(["campaign", "check", str(tmp_path / "p.toml")]) == ExitCode.OK
    assert "[park]" not in capsys.readouterr().out


def test_check_reads_a_campaign_folder_from_its_inputs(tmp_path, capsys):
    folder = tmp_path / "r1"
    run_campaign(load_protocol(protocol_with(tmp_path, None, count=2)), folder, progress=False, report=False, limit=1)
    (tmp_path / "printer.toml").unlink()  # the campaign's own copy is what is checked, not the file it named
    assert main(["campaign", "check", str(folder)]) == ExitCode.OK
    out = capsys.readouterr().out
    assert out.startswith(f"{folder / 'inputs' / 'protocol.toml'}: ok\n  4 presses (2 positions)")


def test_check_of_a_folder_that_is_no_campaign_names_what_it_looked_for(tmp_path, capsys):
    assert main(["campaign", "check", str(tmp_path)]) == ExitCode.CHECK_FAILED
    err = capsys.readouterr().err
    assert f"{tmp_path} is a folder, and no campaign folder (no inputs/protocol.toml in it)" in err
    assert "Is a directory" not in err

"""The protocol's G-code sections and the `neatskin gcode` commands, end to end on real files."""

import tomllib

import pytest

from neatskin.cli import main
from neatskin.errors import ConfigError
from neatskin.gcode.parse import parse_program
from neatskin.gcode.spec import load_gcode_spec, press_spec_from_dict


def test_paper_protocol_sections(protocols_dir):
    spec = load_gcode_spec(protocols_dir / "paper.toml")
    assert (spec.name, spec.seed) == ("paper", 2019)
    assert spec.layout_path == protocols_dir / "skins" / "paper.toml"
    assert spec.printer_path == protocols_dir / "printers" / "paper.toml"
    assert (spec.positions.strategy, spec.positions.count, spec.positions.seed) == ("paper", 100, 2019)
    p = spec.press
    assert (p.depth_mm, p.repeats, p.order, p.hold_s, p.probe_diameter_mm, p.travel_ordering) == (
        3.5,
        28,
        "position",
        1.2,
        5.5,
        False,
    )


def test_protocol_problems_reported_together(protocols_dir):
    data = tomllib.loads((protocols_dir / "paper.toml").read_text())
    data["campaign"]["seed"] = -3
    del data["files"]["printer"]
    data["positions"]["strategy"] = "spiral"
    data["positions"]["cuont"] = 5
    data["press"]["repeats"] = 0
    del data["press"]["depth_mm"]
    with pytest.raises(ConfigError) as info:
        press_spec_from_dict(data, "p.toml")
    assert {p.field for p in info.value.problems} == {
        "campaign.seed",
        "files.printer",
        "positions.strategy",
        "positions.cuont",
        "press.repeats",
        "press.depth_mm",
    }
    assert all(p.file == "p.toml" for p in info.value.problems)


def test_positions_seed_overrides_campaign_seed(protocols_dir):
    data = tomllib.loads((protocols_dir / "paper.toml").read_text())
    data["positions"]["seed"] = 5
    assert press_spec_from_dict(data, str(protocols_dir / "paper.toml")).positions.seed == 5


def test_travel_ordering_with_shuffle_refused(protocols_dir):
    data = tomllib.loads((protocols_dir / "paper.toml").read_text())
    data["press"].update(order="shuffled", travel_ordering=True)
    with pytest.raises(ConfigError) as info:
        press_spec_from_dict(data, "p.toml")
    assert info.value.field == "press.travel_ordering"


def test_generate_then_check(protocols_dir, tmp_path, capsys):
    out = tmp_path / "smoke.gcode"
    assert main(["gcode", "generate", str(protocols_dir / "smoke.toml"), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "6 positions, 12 presses" in printed and "estimated printer time" in printed
    lines = parse_program(out.read_text())
    assert sum(1 for ln in lines if ln.code == "G4") == 12
    again = tmp_path / "again.gcode"
    assert main(["gcode", "generate", str(protocols_dir / "smoke.toml"), "-o", str(again), "--no-hold"]) == 0
    assert "G4" not in again.read_text()
    capsys.readouterr()
    assert main(["gcode", "check", str(out), "--profile", str(protocols_dir / "printers" / "paper.toml")]) == 0
    printed = capsys.readouterr().out
    assert f"{len(lines)} commands, 12 presses" in printed and "bounds: every move inside" in printed


def test_check_flags_out_of_bounds_and_syntax(protocols_dir, tmp_path, capsys):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G28\nG1 X250 Y10 F6000\nG1 Z-1\n")
    assert main(["gcode", "check", str(bad), "--profile", str(protocols_dir / "printers" / "paper.toml")]) == 1
    err = capsys.readouterr().err
    assert "moves X to 250 mm, outside [0, 220] mm" in err and "moves Z to -1 mm" in err
    bad.write_text("G28\nfoo\n")
    assert main(["gcode", "check", str(bad)]) == 1
    assert "line 2" in capsys.readouterr().err


def test_generate_refuses_bad_protocol_before_writing(protocols_dir, tmp_path, capsys):
    text = (protocols_dir / "smoke.toml").read_text().replace('name = "smoke"', 'name = "smoke\\nG28"')
    text = text.replace('"skins/', f'"{protocols_dir}/skins/').replace('"printers/', f'"{protocols_dir}/printers/')
    proto = tmp_path / "evil.toml"
    proto.write_text(text)
    out = tmp_path / "evil.gcode"
    assert main(["gcode", "generate", str(proto), "-o", str(out)]) == 3
    assert "could inject" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_prints_a_calibration_table(capsys):
    assert main(["gcode", "calibrate", "--point", "0,0,95,95,5.5", "--point", "30,0,95,125,5.5"]) == 0
    out = capsys.readouterr().out
    assert "offset_x_mm = 95.000" in out and "rotation_deg = 90.0000" in out and "rms 0.000 mm" in out


def test_check_flags_a_phase_without_m400_and_g92(protocols_dir, tmp_path, capsys):
    out = tmp_path / "p.gcode"
    assert main(["gcode", "generate", str(protocols_dir / "smoke.toml"), "-o", str(out)]) == 0
    text = out.read_text()
    # drop the M400 that ends press 3's descend phase
    head, tail = text.split("M118 E1 NS press=3 phase=descend\n", 1)
    tail = tail.replace("M400\n", "", 1)
    out.write_text(head + "M118 E1 NS press=3 phase=descend\n" + tail)
    capsys.readouterr()
    assert main(["gcode", "check", str(out), "--profile", str(protocols_dir / "printers" / "paper.toml")]) == 1
    assert "phase 'press=3 phase=descend' does not end in M400" in capsys.readouterr().err
    out.write_text("G28\nG92 X0\nG1 X10\n")
    assert main(["gcode", "check", str(out), "--profile", str(protocols_dir / "printers" / "paper.toml")]) == 1
    assert "redefines the coordinate system" in capsys.readouterr().err


def test_generate_writes_positions_csv(protocols_dir, tmp_path):
    import pandas as pd

    csv = tmp_path / "positions.csv"
    assert (
        main(
            [
                "gcode",
                "generate",
                str(protocols_dir / "smoke.toml"),
                "-o",
                str(tmp_path / "s.gcode"),
                "--positions",
                str(csv),
            ]
        )
        == 0
    )
    table = pd.read_csv(csv)
    assert list(table.columns) == ["position_id", "x_mm", "y_mm", "feature"]
    assert table["position_id"].tolist() == list(range(6))
    assert table["feature"].str.split(":").str[0].value_counts().to_dict() == {"channel": 3, "face": 3}


def test_generate_draws_the_positions_png(protocols_dir, tmp_path):
    import matplotlib.image as mpimg

    png = tmp_path / "positions.png"
    assert (
        main(
            [
                "gcode",
                "generate",
                str(protocols_dir / "smoke.toml"),
                "-o",
                str(tmp_path / "s.gcode"),
                "--plot",
                str(png),
            ]
        )
        == 0
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = mpimg.imread(png)
    assert image.shape[:2] == (720, 768)  # 6.4 x 6.0 in at 120 dpi
    red = (image[..., 0] > 0.75) & (image[..., 1] < 0.3) & (image[..., 2] < 0.3)
    assert red.sum() > 50  # the channel positions are drawn

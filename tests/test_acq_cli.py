"""`neatskin mux table`: the technician's switching table."""

from pathlib import Path

from neatskin.cli import main

REPO = Path(__file__).resolve().parent.parent
PAPER = REPO / "protocols" / "wiring" / "paper.toml"


def test_mux_table_paper(capsys):
    assert main(["mux", "table", str(PAPER)]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = [line for line in out if line[:4].strip().isdigit()]
    assert len(rows) == 28
    assert rows[0].split() == [
        "0",
        "1-2",
        "U1",
        "0",
        "1",
        "2",
        "0",
        "0",
        "0",
        "1",
        "1",
        "1",
        "1",
        "1",
        "1",
        "[2,",
        "22)",
        "[22,",
        "122)",
        "2.2",
    ]
    assert rows[27].split()[:15] == ["27", "7-8", "U7", "3", "7", "8", "1", "1", "1", "1", "1", "1", "1", "1", "0"]
    assert "U7.INH=port0/line8" in out[1]
    assert out[-1] == (
        "sweep: 3416 samples = 341.6 ms at 10000 Hz (28 x (2 break + 20 settle + 100 live)); "
        "98 line edges per sweep (pairs order)"
    )


def test_mux_table_options_and_gray_order(capsys):
    assert (
        main(
            [
                "mux",
                "table",
                str(PAPER),
                "--rate-hz",
                "20000",
                "--live-samples",
                "40",
                "--settle-samples",
                "10",
                "--order",
                "gray",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out.splitlines()
    rows = [line.split() for line in out if line[:4].strip().isdigit()]
    assert [r[1] for r in rows[:5]] == ["1-2", "1-3", "1-5", "1-4", "1-8"]
    assert out[-1].startswith("sweep: 1456 samples = 72.8 ms at 20000 Hz") and out[-1].endswith(
        "78 line edges per sweep (gray order)"
    )


def test_mux_table_layout_option_and_errors(tmp_path, capsys):
    text = PAPER.read_text().replace('layout = "../skins/paper.toml"', "")
    no_layout = tmp_path / "board.toml"
    no_layout.write_text(text)
    assert main(["mux", "table", str(no_layout)]) == 3
    assert "names no layout" in capsys.readouterr().err
    assert main(["mux", "table", str(no_layout), "--layout", str(REPO / "protocols" / "skins" / "paper.toml")]) == 0
    capsys.readouterr()
    no_layout.write_text(text.replace("X3 = 7, Y3 = 8", "X3 = 7, Y3 = 7"))
    assert main(["mux", "table", str(no_layout), "--layout", str(REPO / "protocols" / "skins" / "paper.toml")]) == 3
    err = capsys.readouterr().err
    assert "pair with both ends on electrode 7" in err and "not routed" not in err and len(err.splitlines()) == 1
    assert main(["mux", "table", str(PAPER), "--break-samples", "1"]) == 3
    assert "break_samples must be an integer >= 2" in capsys.readouterr().err


def test_mux_table_from_a_protocol(tmp_path, capsys):
    protocol = tmp_path / "p.toml"
    protocol.write_text(
        f'[files]\nwiring = "{PAPER}"\n[acquisition]\nrate_hz = 10000.0\nsettle_samples = 10\n'
        "live_samples = 50\n[press]\nhold_s = 1.0\n"
    )
    assert main(["mux", "table", "--protocol", str(protocol)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-2].startswith("sweep: 1736 samples = 173.6 ms at 10000 Hz (28 x (2 break + 10 settle + 50 live))")
    # (1.0 - 0.005) // 0.1736 = 5
    assert out[-1] == "a 1 s hold: every pair is measured at least 5 times inside it, whatever the sweep's phase"
    assert main(["mux", "table", "--protocol", str(protocol), "--live-samples", "100", "--hold-s", "0.3"]) == 0
    assert (
        capsys.readouterr()
        .out.splitlines()[-1]
        .endswith("at least 0 times inside it, whatever the sweep's phase  <- too short for a pressed value")
    )
    protocol.write_text('[acquisition]\nlive_samples = "many"\n')
    assert main(["mux", "table", "--protocol", str(protocol)]) == 3
    err = capsys.readouterr().err
    assert "[acquisition.live_samples]: 'live_samples' must be an integer, got 'many'" in err
    protocol.write_text("[acquisition]\nrate_hz = 1e12\nlive_sample = 50\n")
    assert main(["mux", "table", "--protocol", str(protocol)]) == 3
    err = capsys.readouterr().err
    assert "[acquisition.rate_hz]: 'rate_hz' = 1000000000000.0 is above 1.25e+06" in err
    assert "[acquisition.live_sample]: unknown key 'live_sample' (fix: did you mean 'live_samples'?)" in err


def test_mux_table_of_a_wiring_whose_layout_is_missing_names_the_wiring(tmp_path, capsys):
    board = tmp_path / "board.toml"
    board.write_text(PAPER.read_text().replace('"../skins/paper.toml"', '"../skins/nope.toml"'))
    assert main(["mux", "table", str(board)]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"neatskin: error: {board}: [layout]: the wiring names layout '../skins/nope.toml', ")
    assert len(err.splitlines()) == 1


def test_mux_table_of_a_layout_file_says_it_is_a_layout(capsys):
    layout = REPO / "protocols" / "skins" / "paper.toml"
    assert main(["mux", "table", str(layout)]) == 3
    err = capsys.readouterr().err
    assert f"{layout}: this is a layout file (it has [skin], " in err and "), not a wiring (fix: " in err

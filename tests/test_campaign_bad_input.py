"""Bad input: every malformed protocol field is named with its fix before motion, and nothing is half-written."""

import os
import shutil
import tty

import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.errors import ConfigError, HardwareError
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign


@pytest.fixture
def protocols(tmp_path):
    root = tmp_path / "protocols"
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    shutil.copy(PROTOCOLS / "smoke.toml", root / "smoke.toml")
    return root


def edit(path, old, new):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new))


@pytest.mark.parametrize(
    "old, new, field, words",
    [
        ("depth_mm = 3.5", "depth_mm = 9.0", "press.depth_mm", "thickness"),
        ("amplitude_a = 0.0002", "amplitude_a = -0.0002", "excitation.amplitude_a", "positive"),
        ("rate_hz = 10000.0", "rate_hz = 1500.0", "excitation.frequency_hz", "Nyquist"),
        ("window = 10", "window = 500", "acquisition.window", "live window"),
        ('demodulation = "rms"', 'demodulation = "fft"', "acquisition.demodulation", "not one of"),
        ('fidelity = "deformation"', 'fidelity = "exact"', "scene.fidelity", "not one of"),
        ("[fsr]\nenabled = true", '[fsr]\nenabled = "yes"', "fsr.enabled", "true or false"),
        ('layout = "skins/paper.toml"', 'layout = "skins/nope.toml"', "files.layout", "does not exist"),
        ("live_samples = 100", "live_sample = 100", "acquisition.live_sample", "did you mean 'live_samples'"),
        ("repeats = 2", "repeats = 0", "press.repeats", ""),
        ('strategy = "stratified"', 'strategy = "spiral"', "positions.strategy", ""),
        ("seed = 7", "seed = -1", "campaign.seed", ""),
    ],
)
def test_each_protocol_mistake_is_named(protocols, old, new, field, words):
    path = protocols / "smoke.toml"
    edit(path, old, new)
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    fields = [p.field for p in info.value.problems]
    assert field in fields, info.value
    problem = info.value.problems[fields.index(field)]
    assert problem.file == str(path) and problem.fix
    assert words in str(problem)


def test_every_error_reported_at_once(protocols):
    path = protocols / "smoke.toml"
    edit(path, "amplitude_a = 0.0002", "amplitude_a = 0")
    edit(path, 'demodulation = "rms"', 'demodulation = "fft"')
    edit(path, "depth_mm = 3.5", "depth_mm = 9.0")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    fields = {p.field for p in info.value.problems}
    assert {"excitation.amplitude_a", "acquisition.demodulation", "press.depth_mm"} <= fields


def test_layout_and_wiring_errors_surface_through_the_protocol(protocols):
    edit(protocols / "skins" / "paper.toml", 'to = "J10"', 'to = "J99"')
    with pytest.raises(ConfigError) as info:
        load_protocol(protocols / "smoke.toml")
    assert any(p.file.endswith("paper.toml") and "J99" in p.message for p in info.value.problems)


def test_out_of_bounds_refused_before_motion(protocols, tmp_path):
    edit(protocols / "printers" / "paper.toml", "offset_x_mm = 95.0", "offset_x_mm = 295.0")
    out = tmp_path / "run"
    with pytest.raises(ConfigError) as info:
        run_campaign(load_protocol(protocols / "smoke.toml"), out, dry_run=True, progress=False, report=False)
    assert "press" in str(info.value)
    assert not out.exists(), "nothing may be written before the plan is valid"


def test_short_hold_refused(protocols):
    edit(protocols / "smoke.toml", "hold_s = 1.2", "hold_s = 0.3")
    protocol = load_protocol(protocols / "smoke.toml")
    from neatskin.rig.plan import build_plan

    with pytest.raises(ConfigError) as info:
        build_plan(protocol)
    assert info.value.field == "press.hold_s" and "hold_s >=" in info.value.problems[0].fix


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_serial_port_that_never_answers(tmp_path):
    master, slave = os.openpty()
    tty.setraw(slave)
    out = tmp_path / "run"
    try:
        with pytest.raises(HardwareError):
            run_campaign(
                load_protocol(PROTOCOLS / "smoke.toml"),
                out,
                dry_run=False,
                port=os.ttyname(slave),
                daq_kind="ni",
                progress=False,
                report=False,
                connect_timeout_s=0.2,
            )
    finally:
        os.close(master)
        os.close(slave)
    assert not out.exists()


@pytest.mark.timeout(60)
def test_missing_daq_is_one_clear_error(tmp_path, capsys):
    pytest.importorskip("serial")
    try:
        import nidaqmx  # noqa: F401

        pytest.skip("nidaqmx is installed here: the missing-DAQ path cannot be shown")
    except ImportError:
        pass
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.sim.printer import SimulatedPrinter

    printer = SimulatedPrinter(load_printer_profile(PROTOCOLS / "printers" / "paper.toml"))
    port = printer.start_pty()
    out = tmp_path / "run"
    try:
        code = main(
            [
                "campaign",
                "run",
                str(PROTOCOLS / "smoke.toml"),
                "--port",
                port,
                "--daq",
                "ni",
                "--out",
                str(out),
                "--no-report",
                "--quiet",
                "--connect-timeout",
                "0.2",
            ]
        )
    finally:
        printer.stop()
    err = capsys.readouterr().err
    assert code == 4 and err.count("neatskin: error:") == 1
    assert "nidaqmx" in err
    assert not out.exists()
    assert printer.executed[-1][1].startswith("M110"), "nothing but the line-number reset may reach the printer"


@pytest.mark.parametrize("campaign", [False, True])
def test_existing_folder_is_not_overwritten(tmp_path, campaign):
    """Resume is offered only for a campaign (a manifest.json): it refuses any other folder (the audit's notes.txt
    folder was told to resume, which then failed on the missing manifest)."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_bytes(b"precious")
    if campaign:
        (out / "manifest.json").write_text("{}")
    with pytest.raises(ConfigError) as info:
        run_campaign(load_protocol(PROTOCOLS / "smoke.toml"), out, dry_run=True, progress=False, report=False)
    problem = info.value.problems[0]
    if campaign:
        assert problem.message == f"the output folder {out} already holds files"
        assert problem.fix == f"choose a new folder, or continue it with: neatskin campaign resume {out}"
    else:
        assert problem.message == f"the output folder {out} already holds files and is no campaign (no manifest.json)"
        assert problem.fix == "choose a new or empty folder for --out"
    assert (out / "notes.txt").read_bytes() == b"precious"
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "notes.txt"][1 - campaign :]


def test_port_that_does_not_exist(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [
            "campaign",
            "run",
            str(PROTOCOLS / "smoke.toml"),
            "--port",
            "/dev/ttyNOPE",
            "--out",
            str(out),
            "--quiet",
            "--no-report",
        ]
    )
    err = capsys.readouterr().err
    assert code == 4 and err.count("neatskin: error:") == 1
    assert "no serial port '/dev/ttyNOPE'" in err and "nothing was sent" in err and "ls /dev/ttyUSB*" in err
    assert not out.exists()


def test_resume_refuses_changed_inputs(tmp_path):
    """A seed edited in the campaign's own copy of the protocol would mix two campaigns: refused, nothing moves."""
    from neatskin.errors import DataError
    from neatskin.rig.runner import resume_campaign

    folder = tmp_path / "run"
    run_campaign(load_protocol(PROTOCOLS / "smoke.toml"), folder, dry_run=True, progress=False, report=False, limit=3)
    parts = sorted((folder / "presses").glob("part-*.parquet"))
    edit(folder / "inputs" / "protocol.toml", "seed = 7", "seed = 8")
    with pytest.raises(DataError) as info:
        resume_campaign(folder, progress=False, report=False)
    problem = info.value.problems[0]
    assert problem.field == "protocol" and "not the file this campaign started with" in problem.message
    assert sorted((folder / "presses").glob("part-*.parquet")) == parts


def test_depth_beyond_the_skin_is_one_error(protocols):
    """Too deep is the depth's fault, not the calibration's: one problem, naming press.depth_mm."""
    path = protocols / "smoke.toml"
    edit(path, "depth_mm = 3.5", "depth_mm = 8.0")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert [p.field for p in info.value.problems] == ["press.depth_mm"]
    assert "set depth_mm <= 5" in info.value.problems[0].fix


@pytest.mark.parametrize(
    "old, new, field, words",
    [
        # values the run cannot execute: each refused by campaign check, before anything moves
        ("hold_s = 1.2", "hold_s = 1e15", "press.hold_s", "is above 3600"),
        ("hold_s = 1.2", "hold_s = inf", "press.hold_s", "must be a finite number"),
        ("rate_hz = 10000.0", "rate_hz = 1e300", "acquisition.rate_hz", "is above 1.25e+06"),
        ("count = 6", "count = 10000000", "positions.count", "is above 100000"),
        ("surface_error_mm = 0.0", "surface_error_mm = -1e308", "scene.surface_error_mm", "within the 5.5 mm skin"),
        ("placement_error_mm = 0.0", "placement_error_mm = 1e9", "scene.placement_error_mm", "beyond 100 mm"),
        ('name = "smoke"', 'name = "smöke"', "campaign.name", "is not a safe file name"),
        ('name = "smoke"', 'name = "../../x"', "campaign.name", "is not a safe file name"),
        ('name = "smoke"', 'name = "/tmp/x"', "campaign.name", "is not a safe file name"),
        ('printer = "printers/paper.toml"', 'printer = "/dev/zero"', "files.printer", "is not a regular file"),
        ('printer = "printers/paper.toml"', f'printer = "{"x" * 5000}.toml"', "files.printer", "more than 1024"),
        ('printer = "printers/paper.toml"', f'printer = "{"x" * 300}.toml"', "files.printer", "File name too long"),
        ("[fsr]", "[fsrr]", "fsrr", "did you mean 'fsr'"),
        ("[fsr]\nenabled = true", "[fsr]\nenable = true", "fsr.enable", "did you mean 'enabled'"),
    ],
)
def test_values_the_run_cannot_execute_are_refused(protocols, old, new, field, words):
    path = protocols / "smoke.toml"
    edit(path, old, new)
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    fields = [p.field for p in info.value.problems]
    assert field in fields, info.value
    problem = info.value.problems[fields.index(field)]
    assert problem.file == str(path) and problem.fix
    assert words in str(problem)


def test_rig_time_and_waveform_bytes_are_capped(protocols):
    path = protocols / "smoke.toml"
    edit(path, "count = 6", "count = 50000")
    edit(path, "repeats = 2", "repeats = 10")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    by_field = {p.field: p for p in info.value.problems}
    # 5e5 presses x (1.2 s hold + 2 x 13.5 mm / 2 mm/s + 0.5 s + 311 mm / 100 mm/s) = 5e5 x 18.31 s
    assert "about 106 days of rig time, beyond the cap of 14 days" in by_field["positions.count"].message
    assert "GiB of waveforms, beyond the cap of 200 GiB" in by_field["record.waveforms"].message


def test_resource_estimate_of_the_smoke_campaign(protocols):
    protocol = load_protocol(protocols / "smoke.toml")
    r = protocol.resources
    # hold 1.2 s + (10 mm safe height + 3.5 mm depth) x 2 / 2 mm/s + 0.5 s = 15.2 s at 10 kHz
    assert (r.presses, r.samples_per_press, r.bytes_per_press) == (12, 152_000, 152_000 * 24)
    assert r.waveform_bytes == 12 * 152_000 * 24
    assert r.rig_time_s == pytest.approx(12 * (15.2 + (220 * 2**0.5) / 100) + 25.0)


def test_non_utf8_protocol_is_one_error(protocols):
    path = protocols / "smoke.toml"
    path.write_bytes(path.read_bytes().replace(b"smoke test", b"smoke \xff test"))
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert len(info.value.problems) == 1 and info.value.file == str(path)
    assert "not UTF-8" in str(info.value)


def test_the_papers_2_mA_clips_at_the_mux_rails(protocols):
    path = protocols / "smoke.toml"
    edit(path, "amplitude_a = 0.0002", "amplitude_a = 0.002")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert [p.field for p in info.value.problems] == ["excitation.amplitude_a"]
    problem = info.value.problems[0]
    # 5625 ohm (corner to opposite corner, 1.5 R) x 1.5 + 2 x 100 + 10 = 8647.5 ohm; x 2 mA = 17.3 V
    assert "2 mA x (5625 ohm (pair 2-6, undeformed) x 1.5 press margin" in problem.message
    assert "= 17.3 V peak, beyond the mux supply rails (-8 V .. +8 V): 8 V" in problem.message
    assert "lower amplitude_a to <= 0.925 mA" in problem.fix and "more conductive fluid" in problem.fix
    # the skin's file as seen from the protocol's folder: a bare "paper.toml" would read as the protocol's own
    assert "resistivity_ohm_m = 0.5 ohm m in skins/paper.toml)" in problem.fix


def test_electrical_limits_come_from_the_wiring_and_the_protocol(protocols):
    edit(protocols / "wiring" / "paper.toml", "supply_positive_v = 8.0", "supply_positive_v = 15.0")
    edit(protocols / "wiring" / "paper.toml", "supply_negative_v = -8.0", "supply_negative_v = -15.0")
    path = protocols / "smoke.toml"
    edit(path, "[acquisition]", "[acquisition]\nadc_range_v = 2.0")
    edit(path, "amplitude_a = 0.0002", "amplitude_a = 0.001")
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    # rails now +-15 V; the ADC reaches 2 V / 0.5 = 4 V across the pair: 1 mA x 8647.5 ohm = 8.65 V
    assert "8.65 V peak, beyond the ADC range over the voltage gain" in info.value.problems[0].message
    edit(path, "adc_range_v = 2.0", "adc_range_v = 10.0")
    check = load_protocol(path).electrical
    assert (check.peak_v, check.limit_v) == (pytest.approx(8.6475), 15.0)
    assert check.limit_name.startswith("mux supply rails")


# A technician's mistakes, one at a time, through `campaign check` as typed at the shell (QA of the config
# layer): each is exactly one problem naming the file and the field, exit code 2, no traceback. Each case
# cascaded, passed, or printed a raw value before (docs/config.md, "Mistakes and what they print").
ONE_MISTAKE = [
    ("smoke.toml", "[campaign]", "[campain]", "campain", "did you mean 'campaign'?"),
    ("smoke.toml", 'name = "smoke"', 'nme = "smoke"', "campaign.nme", "did you mean 'name'?"),
    ("smoke.toml", "[press]\n", "[pres]\n", "pres", "did you mean 'press'?"),
    ("smoke.toml", "[press]\n", "[[press]]\n", "press", "written as an array of tables [[press]]"),
    ("smoke.toml", "frequency_hz = 1000.0", "frequency_hz = 1.0", "excitation.frequency_hz", "0.01 periods"),
    ("smoke.toml", "rate_hz = 10000.0", "rate_hz = 10.0", "excitation.frequency_hz", "10 kHz is rate_hz = 10000.0"),
    ("smoke.toml", "probe_diameter_mm = 5.5", "probe_diameter_mm = 55", "press.probe_diameter_mm", "wider than"),
    ("skins/paper.toml", "[[junctions]]", "[[junction]]", "junction", "did you mean 'junctions'?"),
    ("skins/paper.toml", "x_mm = 15.0", 'x_mm = "15.0"', "junctions[1].x_mm", "must be a finite number"),
    ("skins/paper.toml", 'name = "J22"', 'name = "J21"', "junctions[8].name", "duplicate junction name 'J21'"),
    ("skins/paper.toml", "width_mm = 2.0", "widht_mm = 2.0", "channel_defaults.widht_mm", "did you mean"),
    ("skins/paper.toml", "[skin]", "[[skin]]", "skin", "written as an array of tables [[skin]]"),
    ("wiring/paper.toml", "X3 = 7, Y3 = 8", "X3 = 1, Y3 = 2", "chips[6].pins.X3/Y3", "not routed by any chip: 7-8"),
    ("wiring/paper.toml", "X3 = 7, Y3 = 8", "X3 = 7, Y3 = 9", "chips[6].pins.Y3", "electrode 9 on pin Y3"),
    ("wiring/paper.toml", "X0 = 1, Y0 = 2,", "X0 = 1, YO = 2,", "chips[0].pins.YO", "did you mean 'Y0'?"),
    ("wiring/paper.toml", '"../skins/paper.toml"', '"../skins/paper2.toml"', "layout", "does not exist"),
    ("printers/paper.toml", "offset_x_mm = 95.0", "offset_x_mm = 250.0", "press 0", "so do 11 more presses"),
    ("skins/paper.toml", "width_mm = 2.0", "width_mm = 0.0", "channel_defaults.width_mm", "must be positive"),
    ("wiring/paper.toml", '[[chips]]\nname = "U7"', '[[chipz]]\nname = "U7"', "chipz", "did you mean 'chips'?"),
]


@pytest.mark.parametrize("name, old, new, field, words", ONE_MISTAKE, ids=[f"{c[0]}:{c[2][:24]}" for c in ONE_MISTAKE])
def test_one_mistake_is_one_problem(protocols, capsys, name, old, new, field, words):
    path = protocols / name
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))  # one mistake: the first occurrence only
    assert main(["campaign", "check", str(protocols / "smoke.toml")]) == 1
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    reported_in = protocols / ("smoke.toml" if field.startswith("press ") else name)  # presses are the protocol's
    assert f"{reported_in}: [{field}]: " in lines[0] and words in lines[0] and "(fix: " in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("name", ["smoke.toml", "skins/paper.toml"])
def test_an_empty_file_is_one_problem(protocols, capsys, name):
    (protocols / name).write_text("")
    assert main(["campaign", "check", str(protocols / "smoke.toml")]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{protocols / name}: the file is empty (fix: write its tables (" in lines[0]


@pytest.mark.parametrize("name", ["smoke.toml", "skins/paper.toml", "wiring/paper.toml", "printers/paper.toml"])
def test_a_byte_order_mark_or_crlf_line_ends_are_read_as_the_same_file(protocols, name):
    clean = load_protocol(protocols / "smoke.toml")
    path = protocols / name
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes().replace(b"\n", b"\r\n"))
    again = load_protocol(protocols / "smoke.toml")
    assert again.layout.xy_mm.tolist() == clean.layout.xy_mm.tolist()
    assert (again.press, again.excitation, again.acquisition) == (clean.press, clean.excitation, clean.acquisition)
    assert again.printer.calibration == clean.printer.calibration and again.wiring.routes == clean.wiring.routes


def test_a_wiring_drawn_for_another_skin_is_refused(protocols):
    other = (protocols / "skins" / "paper.toml").read_text().replace('name = "neatskin-paper"', 'name = "other"')
    (protocols / "skins" / "other.toml").write_text(other)
    edit(protocols / "wiring" / "paper.toml", '"../skins/paper.toml"', '"../skins/other.toml"')
    with pytest.raises(ConfigError) as info:
        load_protocol(protocols / "smoke.toml")
    [problem] = info.value.problems
    assert problem.field == "layout" and problem.file == str(protocols / "wiring" / "paper.toml")
    assert (
        problem.message
        == "the wiring was drawn for layout 'other' (../skins/other.toml), the protocol uses 'neatskin-paper'"
    )


def test_electrical_summary_of_the_smoke_campaign(protocols):
    # 0.2 mA x (5625 ohm x 1.5 + 2 x 100 ohm + 10 ohm) = 1.7295 V against the +-8 V rails
    summary = load_protocol(protocols / "smoke.toml").electrical.summary()
    assert summary == (
        "peak 1.73 V (pair 2-6, 5625 ohm undeformed, with the press margin and R_on), "
        "limit 8.00 V (mux supply rails (-8 V .. +8 V)), 4.63x headroom"
    )


@pytest.mark.parametrize(
    "key, named, kind, own",
    [
        ("wiring", "skins/paper.toml", "layout", "wiring"),
        ("printer", "wiring/paper.toml", "wiring", "printer profile"),
        ("layout", "printers/paper.toml", "printer profile", "layout"),
    ],
)
def test_a_file_of_another_kind_is_one_problem(protocols, capsys, key, named, kind, own):
    edit(protocols / "smoke.toml", f'{key} = "', f'{key} = "{named}" # was "')
    assert main(["campaign", "check", str(protocols / "smoke.toml")]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"{protocols / named}: this is a {kind} file (it has [" in lines[0]
    assert f"), not a {own} (fix: name a {own} file here" in lines[0]


@pytest.mark.parametrize("command", [["campaign", "check"], ["gcode", "generate", "-o", "out.gcode"]])
def test_a_printer_profile_given_as_the_protocol_is_one_problem(protocols, capsys, command):
    path = protocols / "printers" / "paper.toml"
    assert main([*command[:2], str(path), *command[2:]]) == (
        1 if command[0] == "campaign" else 3
    )  # a failed check; a bad input
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{path}: this is a printer profile file (it has [printer], [bed]," in lines[0]
    assert lines[0].endswith(
        "), not a protocol (fix: name a protocol file here: check the protocol's [files] entry or the path given)"
    )


def test_a_loop_of_links_in_files_is_one_config_error_naming_the_field(protocols, tmp_path, capsys):
    """`ln -s loop.toml loop.toml` as the layout: Python 3.11's Path.resolve() raises RuntimeError, not OSError."""
    (protocols / "loop.toml").symlink_to("loop.toml")
    path = protocols / "smoke.toml"
    edit(path, 'layout = "skins/paper.toml"', 'layout = "loop.toml"')
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    (problem,) = [p for p in info.value.problems if p.field == "files.layout"]
    assert problem.file == str(path) and "loop of symbolic links" in problem.message and "'loop.toml'" in problem.fix
    out = tmp_path / "out"
    for argv, code in (
        (["campaign", "check", str(path)], 1),
        (["campaign", "plan", str(path)], 3),
        (["campaign", "run", str(path), "--dry-run", "-o", str(out), "--no-report", "-q"], 3),
    ):
        assert main(argv) == code, argv
        err = capsys.readouterr().err
        assert "Traceback" not in err and f"{path}: [files.layout]: layout file path cannot be used" in err, err
    assert not out.exists()  # refused before the campaign folder was made
    assert main(["campaign", "resume", str(protocols / "loop.toml"), "--no-report"]) == 5
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{protocols / 'loop.toml'}: not a campaign folder" in err


# ---- fix texts that fit their failure (HOSTILE #14): each says what the user can do, through the real CLI --------


def _neatskin(*argv, privileged=True, cwd=None):
    """`neatskin ARGV` in a child; privileged=False: as root without CAP_DAC_OVERRIDE (mode bits then bind it)."""
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(PROTOCOLS.parent)}
    prefix = []
    if not privileged and os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("root without setpriv: mode bits cannot bind this test")
        caps = "-dac_override,-dac_read_search"
        prefix = ["setpriv", f"--inh-caps={caps}", f"--bounding-set={caps}"]
    return subprocess.run(
        [*prefix, sys.executable, "-m", "neatskin", *argv],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        cwd=cwd,
    )


@pytest.mark.parametrize("port", ["plain", os.devnull, "folder"])
def test_a_file_given_as_the_serial_port_is_not_a_cable_problem(tmp_path, port):
    program = tmp_path / "p.gcode"
    program.write_text("G28\n")
    if port == "plain":
        port = str(tmp_path / "plain")
        (tmp_path / "plain").write_text("")
    elif port == "folder":  # `--port /tmp`: was "the serial port died ... Is a directory (fix: check the USB cable"
        port = str(tmp_path)
    done = _neatskin("printer", "send", str(program), "--port", port, "-q")
    assert done.returncode == 4, done.stderr
    assert done.stderr.startswith(f"neatskin: error: not a serial port {port!r}: ")
    assert "nothing was sent (fix: give the printer's serial device (ls /dev/ttyUSB* /dev/ttyACM*)" in done.stderr
    assert "USB cable" not in done.stderr and "Traceback" not in done.stderr


def test_a_folder_given_as_the_campaigns_port_is_not_a_serial_port(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["campaign", "run", str(PROTOCOLS / "smoke.toml"), "--port", str(tmp_path), "--daq", "simulated"]
    assert main([*argv, "--out", str(out), "--quiet", "--no-report"]) == 4
    err = capsys.readouterr().err
    assert err.startswith(f"neatskin: error: not a serial port {str(tmp_path)!r}: it is a folder: ")
    assert err.count("neatskin: error:") == 1 and "USB cable" not in err and "died" not in err
    assert "nothing was sent (fix: give the printer's serial device" in err and not out.exists()


def test_resume_given_a_protocol_file_asks_for_the_campaign_folder(tmp_path):
    done = _neatskin("campaign", "resume", str(PROTOCOLS / "smoke.toml"))
    assert done.returncode == 3, done.stderr
    assert "[folder]:" in done.stderr and "--out" not in done.stderr  # resume has no --out
    assert "give the campaign folder that `neatskin campaign run` wrote (it holds manifest.json)" in done.stderr


def test_a_new_campaign_that_cannot_be_written_says_run_it_again_not_resume(tmp_path):
    """The new folder is removed on the error: there is nothing to resume."""
    parent = tmp_path / "ro"
    parent.mkdir()
    parent.chmod(0o555)
    try:
        done = _neatskin(
            "campaign", "run", str(PROTOCOLS / "smoke.toml"), "--dry-run", "-o", str(parent / "x"), "-q",
            "--no-report", privileged=False,
        )  # fmt: skip
    finally:
        parent.chmod(0o755)
    assert done.returncode == 5, done.stderr
    assert "Permission denied (fix: give your user write permission on the folder (chmod u+w), then run the " in (
        done.stderr
    )
    assert "resume" not in done.stderr and not list(parent.iterdir())


def test_a_wiring_file_without_permission_or_in_a_loop_of_links_gets_its_own_fix(protocols):
    """Before: 'Permission denied (fix: give a shorter path ...)', and a loop of links was a RuntimeError
    traceback (Python 3.11's Path.resolve) in campaign check, run and plan."""
    locked = protocols / "locked"
    locked.mkdir()
    shutil.copy(protocols / "wiring" / "paper.toml", locked / "w.toml")
    smoke = protocols / "smoke.toml"
    edit(smoke, 'wiring = "wiring/paper.toml"', 'wiring = "locked/w.toml"')
    locked.chmod(0)
    try:
        denied = _neatskin("campaign", "check", str(smoke), privileged=False)
    finally:
        locked.chmod(0o755)
    assert denied.returncode == 1, denied.stderr
    assert "[files.wiring]: wiring file path cannot be used: Permission denied (fix: give your user read " in (
        denied.stderr
    )
    assert "shorter path" not in denied.stderr
    (protocols / "loop.toml").symlink_to("loop.toml")
    edit(smoke, 'wiring = "locked/w.toml"', 'wiring = "loop.toml"')
    for command in (["campaign", "check"], ["campaign", "run", "--dry-run", "-o", str(protocols / "r")]):
        looped = _neatskin(*command[:2], str(smoke), *command[2:])
        assert looped.returncode in (1, 3) and "Traceback" not in looped.stderr, looped.stderr
        assert "the path runs through a loop of symbolic links: point it at the TOML file itself" in looped.stderr


@pytest.mark.parametrize(
    "old, new, field",
    [
        ('preset = "ideal"', 'preset = "idael"', "scene.preset"),
        ("placement_error_mm = 0.0", "placement_error_mm = nan", "scene.placement_error_mm"),
        ('signal = "waveforms"', 'signal = "wavefroms"', "scene.signal"),
    ],
)
def test_a_bad_scene_value_is_one_error_not_a_second_about_record_waveforms(protocols, capsys, old, new, field):
    """smoke.toml records waveforms with signal = "waveforms": a bad preset, a NaN or a misspelt signal is that
    one error; the scene's default signal ("features") standing in must not add 'record.waveforms = true needs
    the waveforms to be simulated' (HOSTILE #15)."""
    smoke = protocols / "smoke.toml"
    edit(smoke, old, new)
    assert main(["campaign", "check", str(smoke)]) == 1
    errors = capsys.readouterr().err.splitlines()
    assert len(errors) == 1 and f"[{field}]:" in errors[0], errors


def test_features_with_recorded_waveforms_is_still_refused(protocols, capsys):
    """The negative control: the cross-check itself still fires when the scene really says features."""
    smoke = protocols / "smoke.toml"
    edit(smoke, 'signal = "waveforms"', 'signal = "features"')
    assert main(["campaign", "check", str(smoke)]) == 1
    (error,) = capsys.readouterr().err.splitlines()
    assert "[scene.signal]: record.waveforms = true needs the waveforms to be simulated" in error

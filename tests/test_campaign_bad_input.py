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
        ("amplitude_a = 0.002", "amplitude_a = -0.002", "excitation.amplitude_a", "positive"),
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
    edit(path, "amplitude_a = 0.002", "amplitude_a = 0")
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
    from neatskin.rig.runner import build_plan

    with pytest.raises(ConfigError) as info:
        build_plan(protocol)
    assert info.value.field == "press.hold_s" and "hold_s >=" in info.value.problems[0].fix


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
    assert code == 2 and err.count("neatskin: error:") == 1
    assert "nidaqmx" in err
    assert not out.exists()
    assert printer.executed[-1][1].startswith("M110"), "nothing but the line-number reset may reach the printer"


def test_existing_folder_is_not_overwritten(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "presses.parquet").write_bytes(b"precious")
    with pytest.raises(ConfigError) as info:
        run_campaign(load_protocol(PROTOCOLS / "smoke.toml"), out, dry_run=True, progress=False, report=False)
    assert "resume" in info.value.problems[0].fix
    assert (out / "presses.parquet").read_bytes() == b"precious"


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
    assert code == 2 and err.count("neatskin: error:") == 1
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

"""Scenes: a run builds and imports only what its protocol asks for; missed presses are retried and flagged;
a protocol without an FSR says so; Ctrl-C leaves a resumable campaign with the probe lifted."""

import json
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.marlin.wirelog import read_wire_log
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign


def make_protocol(tmp_path, *replacements, name="scene.toml"):
    root = tmp_path / "protocols"
    if not root.exists():
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    path = root / name
    path.write_text(text)
    return path


FEATURES = (("waveforms = true", "waveforms = false"), ('signal = "waveforms"', 'signal = "features"'))


def test_features_scene_generates_no_waveforms(tmp_path, monkeypatch):
    from neatskin.sim.daq import SimulatedDAQ

    def refuse(*args, **kwargs):
        raise AssertionError("a features-only scene must not generate waveforms")

    monkeypatch.setattr(SimulatedDAQ, "acquire", refuse)
    path = make_protocol(tmp_path, *FEATURES, ("repeats = 2", "repeats = 1"))
    result = run_campaign(load_protocol(path), tmp_path / "run", progress=False, report=False)
    assert result.completed == 6
    assert not (tmp_path / "run" / "waveforms").exists()


def test_network_scene_skips_the_deformation_integral(tmp_path, monkeypatch):
    import neatskin.skin.model as model

    def refuse(*args, **kwargs):
        raise AssertionError("a network-fidelity scene must not integrate the deformation")

    monkeypatch.setattr(model, "resistance_factor", refuse)
    path = make_protocol(
        tmp_path, *FEATURES, ("repeats = 2", "repeats = 1"), ('fidelity = "deformation"', 'fidelity = "network"')
    )
    result = run_campaign(load_protocol(path), tmp_path / "run", progress=False, report=False)
    df = pd.read_parquet(tmp_path / "run" / "presses.parquet")
    assert result.completed == 6 and (df.filter(like="dR_ohm_").abs().max(axis=1) > 100).all()


def test_missed_press_is_retried_then_flagged(tmp_path):
    """The skin lies 5 mm below where the printer was calibrated: a 3.5 mm press never touches it."""
    path = make_protocol(
        tmp_path,
        *FEATURES,
        ("repeats = 2", "repeats = 1"),
        ("surface_error_mm = 0.0", "surface_error_mm = 5.0"),
        ("[fsr]\nenabled = true", "[fsr]\nenabled = true\npause_after_misses = 0"),  # no automatic pause here
    )
    run_campaign(load_protocol(path), tmp_path / "run", progress=False, report=False)
    df = pd.read_parquet(tmp_path / "run" / "presses.parquet")
    for flags in df["flags"]:
        assert list(flags[:3]) == ["fsr_retry:1", "fsr_retry:2", "fsr_missed"]
    assert df.fsr_peak_n.isna().all()
    assert np.abs(df.filter(like="dR_ohm_").to_numpy()).max() < 5.0  # nothing pressed: noise only
    log = read_wire_log(tmp_path / "run" / "wire.log")
    sent = b"".join(data for direction, data in log if direction == ">").decode()
    assert sent.count("phase=press") == 3 * 6  # every press sent three times


def test_protocol_without_fsr_says_so(tmp_path):
    path = make_protocol(
        tmp_path, *FEATURES, ("repeats = 2", "repeats = 1"), ("[fsr]\nenabled = true", "[fsr]\nenabled = false")
    )
    run_campaign(load_protocol(path), tmp_path / "run", progress=False, report=False)
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["labels"].startswith("motion sync only")
    df = pd.read_parquet(tmp_path / "run" / "presses.parquet")
    assert df.fsr_peak_n.isna().all() and (df.filter(like="dR_ohm_").abs().max(axis=1) > 100).all()


PROBE_MODULES = (
    "nidaqmx",
    "neatskin.acquisition.daq.nidaqmx_backend",
    "neatskin.skin.model",
    "neatskin.sim.printer",
    "neatskin.sim.daq",
)


def _modules_after(args, cwd):
    code = (
        f"import sys\nfrom neatskin.cli import main\ncode = main({args!r})\n"
        f"print(sorted(m for m in {PROBE_MODULES!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, timeout=120)
    return out


def test_dry_run_never_imports_nidaqmx(tmp_path):
    path = make_protocol(tmp_path, *FEATURES, ("repeats = 2", "repeats = 1"))
    out = _modules_after(
        ["campaign", "run", str(path), "--dry-run", "--out", str(tmp_path / "run"), "--no-report", "--quiet"], tmp_path
    )
    loaded = eval(out.stdout.strip().splitlines()[-1])
    assert "nidaqmx" not in loaded and "neatskin.acquisition.daq.nidaqmx_backend" not in loaded
    assert "neatskin.skin.model" in loaded  # the probe works: the dry run did build its simulator


@pytest.mark.timeout(120)
def test_real_run_never_builds_a_simulator(tmp_path):
    """The printer is a separate `neatskin sim printer` process; the run fails on the missing NI DAQ."""
    sim = subprocess.Popen([sys.executable, "-m", "neatskin", "sim", "printer"], stdout=subprocess.PIPE, text=True)
    try:
        port = sim.stdout.readline().strip()
        assert port.startswith("/dev/")
        out = _modules_after(
            [
                "campaign",
                "run",
                str(PROTOCOLS / "smoke.toml"),
                "--port",
                port,
                "--daq",
                "ni",
                "--out",
                str(tmp_path / "run"),
                "--no-report",
                "--quiet",
                "--connect-timeout",
                "0.3",
            ],
            tmp_path,
        )
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(10)
    loaded = eval(out.stdout.strip().splitlines()[-1])
    simulators = {"neatskin.skin.model", "neatskin.sim.printer", "neatskin.sim.daq"}
    assert not simulators & set(loaded), loaded
    assert "neatskin.acquisition.daq.nidaqmx_backend" in loaded  # the probe works: the real run reached its DAQ
    assert "neatskin: error:" in out.stderr and "nidaqmx" in out.stderr


def _sent_commands(wire_log) -> list[str]:
    """The command lines the host sent, in order, without their line numbers and checksums."""
    sent = b"".join(data for direction, data in read_wire_log(wire_log) if direction == ">").decode()
    return [re.sub(r"^N\d+ ", "", line).split("*")[0] for line in sent.splitlines() if line.strip()]


def _assert_ends_with_lift_and_park(wire_log, protocol_path) -> None:
    """The last press ran to its lift phase, then the probe went up and parked (the postamble's first three
    moves and M400), and nothing came after."""
    from neatskin.rig.plan import build_plan

    post = build_plan(load_protocol(protocol_path)).program.postamble
    sent = _sent_commands(wire_log)
    last_lift = max(i for i, line in enumerate(sent) if "phase=lift" in line)
    assert sent[last_lift + 1 :] == ["G0 Z15.5 F300", "M400", *post[:3], "M400"], sent[last_lift - 8 :]
    assert post[1].startswith("G0 X") and float(post[2].split("Z")[1].split()[0]) >= 15.5  # park, then up


def _signal_once_written(args, folder, parts, signum):
    """Run `neatskin ARGS` in a child, send it `signum` once `parts` presses are on disk (within 60 s), and return
    (process, stdout, stderr) when it has ended (within 60 s more)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "neatskin", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list((folder / "presses").glob("part-*.parquet"))) < parts:
        time.sleep(0.02)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=60)
    return proc, stdout, stderr


# Ctrl-C; SIGTERM (systemctl stop, docker stop, timeout); SIGHUP (a dropped SSH session): one stop path
@pytest.mark.slow
@pytest.mark.timeout(180)
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_ctrl_c_stops_after_the_press_in_flight_and_resumes(tmp_path, signum):
    path = make_protocol(tmp_path, *FEATURES, ("repeats = 2", "repeats = 40"))
    folder = tmp_path / "run"
    proc, stdout, stderr = _signal_once_written(
        ["campaign", "run", str(path), "--dry-run", "--out", str(folder), "--no-report", "--quiet"], folder, 3, signum
    )
    assert proc.returncode == 130, stderr
    assert "interrupted" in stdout and "resume" in stdout and "Traceback" not in stderr
    assert f"{signum.name}: press" in stderr and "the probe lifts and parks" in stderr
    manifest = json.loads((folder / "manifest.json").read_text())
    done = len(list((folder / "presses").glob("part-*.parquet")))
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == done < 240
    _assert_ends_with_lift_and_park(folder / "wire.log", path)
    result = resume_campaign(folder, progress=False, report=False)
    rows = pd.read_parquet(folder / "presses.parquet")
    assert result.completed == 240 and rows.press_id.is_unique and len(rows) == 240


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_lost_terminal_stops_the_campaign_as_ctrl_c_does(tmp_path):
    """A dropped SSH session: the campaign's controlling terminal (a real pty, progress bar on) hangs up, the kernel
    sends SIGHUP, and writes to that terminal fail from then on. The press in flight finishes, the probe lifts and
    parks, the manifest says interrupted (exit 130, no traceback on a dead terminal), and resume completes it."""
    import fcntl
    import os
    import pty
    import struct
    import termios
    import threading

    path = make_protocol(tmp_path, *FEATURES, ("repeats = 2", "repeats = 40"))
    folder = tmp_path / "run"
    master, slave = pty.openpty()
    fcntl.ioctl(master, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # a terminal 120 columns wide

    def controlling_terminal() -> None:  # in the child, after setsid: the pty becomes its terminal
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)

    proc = subprocess.Popen(
        [sys.executable, "-m", "neatskin", "campaign", "run", str(path), "--dry-run", "--out", str(folder)]
        + ["--no-report"],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        start_new_session=True,
        preexec_fn=controlling_terminal,
    )
    os.close(slave)
    shown = bytearray()

    def drain() -> None:  # the terminal's reader, until the terminal goes away
        try:
            while chunk := os.read(master, 4096):
                shown.extend(chunk)
        except OSError:
            pass

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(list((folder / "presses").glob("part-*.parquet"))) < 3:
            time.sleep(0.02)
        assert proc.poll() is None, bytes(shown)
        os.close(master)  # the hang-up
        assert proc.wait(60) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    assert b"press" in bytes(shown)  # the progress bar was on the terminal
    manifest = json.loads((folder / "manifest.json").read_text())
    done = len(list((folder / "presses").glob("part-*.parquet")))
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == done < 240
    _assert_ends_with_lift_and_park(folder / "wire.log", path)
    assert resume_campaign(folder, progress=False, report=False).completed == 240
    assert pd.read_parquet(folder / "presses.parquet").press_id.is_unique


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_sigterm_during_resume_stops_it_as_ctrl_c_does(tmp_path):
    """`campaign resume` (its own handler) under SIGTERM: exit 130, lift and park, still resumable, and the
    campaign completes with every press once."""
    path = make_protocol(tmp_path, *FEATURES, ("repeats = 2", "repeats = 40"))
    folder = tmp_path / "run"
    first = run_campaign(load_protocol(path), folder, progress=False, report=False, limit=3)
    assert first.completed == 3
    proc, stdout, stderr = _signal_once_written(
        ["campaign", "resume", str(folder), "--no-report", "--quiet"], folder, 6, signal.SIGTERM
    )
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert "SIGTERM: press" in stderr and "interrupted" in stdout
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and 3 < manifest["counts"]["completed"] < 240
    _assert_ends_with_lift_and_park(folder / "wire.log", path)
    assert resume_campaign(folder, progress=False, report=False).completed == 240
    rows = pd.read_parquet(folder / "presses.parquet")
    assert len(rows) == 240 and rows.press_id.is_unique

"""Conformance against the real Marlin firmware (../shared/marlin, native build) behind our relay on a pty.

The oracle is the firmware's own `M111 S1` echo (`echo:N12 G1 Z2 F120*1` for every command it
executes): every line of a program must be echoed exactly once, in order, whatever the relay did
to the line (a corrupted checksum, an `ok` dropped). Both builds: plain `ok` and ADVANCED_OK.
Motion runs in real time on the firmware, so programs are short and never home (G28 takes 30 s
on the simulated board): G92 declares the position instead.
Skips with the reason when the firmware folder is absent.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.marlin.replies import PROBE_TAG
from neatskin.sim.realmarlin import ADVANCED_OK, PLAIN, FirmwareRelay, find_marlin_dir

REPO = Path(__file__).resolve().parent.parent
MARLIN = find_marlin_dir(REPO)
pytestmark = pytest.mark.skipif(
    MARLIN is None,
    reason="the real firmware is absent: no shared/marlin beside the repository (or $NEATSKIN_MARLIN_DIR)",
)
PROFILE = REPO / "protocols" / "printers" / "paper.toml"
BUILDS = [PLAIN, ADVANCED_OK]


def program_lines(n_tags: int = 24) -> list[str]:
    """Commands that run at once (M118 tags, G92) and a few short real moves."""
    lines = ["G90", "G92 X50 Y50 Z10"]
    lines += [f"M118 E1 tag{i}" for i in range(n_tags)]
    lines += [f"G1 Z{10 + (i % 3) * 0.2:.1f} F600" for i in range(8)]
    lines += ["M400", "M118 E1 done"]
    return lines


def ran(relay: FirmwareRelay) -> list[str]:
    """The commands the firmware echoed (it echoes from the line after `M111 S1` on), without the driver's probes."""
    return [cmd for _, cmd in relay.executed() if PROBE_TAG not in cmd]


@pytest.fixture(params=BUILDS)
def relay(request):
    assert MARLIN is not None
    with FirmwareRelay(MARLIN / request.param) as relay:
        yield relay


def driver_for(relay: FirmwareRelay, **config) -> MarlinDriver:
    cfg = DriverConfig(boot_timeout_s=0.1, min_timeout_s=0.5, confirm_batches=True, **config)
    driver = MarlinDriver.open(relay.path, config=cfg, profile=load_printer_profile(PROFILE))
    driver.connect()
    driver.send("M111 S1")
    return driver


@pytest.mark.timeout(60)
def test_exactly_once_with_a_corrupted_line_and_a_lost_ok(relay):
    program = program_lines()
    relay.faults.corrupt.append("tag5")
    relay.faults.drop_ok_after.append("tag12")
    driver = driver_for(relay)
    try:
        assert driver.send_lines(program) == len(program)
        stats = dict(driver.stats)
    finally:
        driver.close()
    assert ran(relay) == program  # the firmware's own echo: every line once, in order
    assert len(relay.corrupted) == 1 and len(relay.dropped) == 1
    assert stats["comm_errors"] == 1 and stats["lines_resent"] == 1
    assert stats["oks_recovered"] >= 1 or relay.binary.name == ADVANCED_OK  # ADVANCED_OK: the next ok names it


@pytest.mark.timeout(60)
def test_lines_in_flight_follow_the_firmwares_buffer(relay):
    """Up to 4 lines in flight (once ADVANCED_OK names them), with a corrupted line in the middle."""
    program = program_lines(40)
    relay.faults.corrupt.append("tag20")
    driver = driver_for(relay, max_in_flight=4)
    try:
        driver.send_lines(program)
        stats = dict(driver.stats)
    finally:
        driver.close()
    assert ran(relay) == program
    if relay.binary.name == ADVANCED_OK:
        assert stats["max_in_flight"] > 1
    else:
        assert stats["max_in_flight"] <= 2  # one line and, at most, the lost-ok probe


@pytest.mark.timeout(90)
@pytest.mark.slow
def test_a_short_press_program(relay):
    """Three presses at real speed: lower to the surface, press, dwell, lift; the probe ends where the program left it."""
    presses = []
    for x in (100, 102, 104):
        presses += [f"G0 X{x} Y100 F6000", "G1 Z5.5 F300", "G1 Z5.0 F120", "G4 P100", "G1 Z7.5 F300", "M400"]
    program = ["G90", "G92 X95 Y100 Z7.5", *presses, "M118 E1 presses done"]
    relay.faults.corrupt.append("X102")
    relay.faults.drop_ok_after.append("G4 P100")
    driver = driver_for(relay)
    try:
        driver.send_lines(program)
        where = driver.position()
    finally:
        driver.close()
    assert ran(relay)[: len(program)] == program
    assert (where.x_mm, where.y_mm, where.z_mm) == (104.0, 100.0, 7.5)


@pytest.mark.timeout(90)
def test_printer_send_exits_0_with_noise(tmp_path):
    """The CLI against both builds in one run: a corrupted line and a lost `ok`, exit 0, every line once."""
    assert MARLIN is not None
    for build in BUILDS:
        gcode = tmp_path / f"{build}.gcode"
        program = program_lines(12)
        gcode.write_text("M111 S1\n" + "\n".join(program) + "\n")
        with FirmwareRelay(MARLIN / build) as relay:
            relay.faults.corrupt.append("tag3")
            relay.faults.drop_ok_after.append("tag8")
            done = subprocess.run(
                [sys.executable, "-m", "neatskin", "printer", "send", "--port", relay.path, "--no-progress"]
                + ["--boot-timeout-s", "0.1", str(gcode)],
                capture_output=True,
                text=True,
                cwd=REPO,
                timeout=60,
                env={**os.environ, "PYTHONPATH": str(REPO)},
            )
            assert done.returncode == 0, done.stderr
            assert f"sent {len(program) + 1} lines" in done.stdout
            assert ran(relay) == program
            assert relay.corrupted and relay.dropped


@pytest.mark.timeout(90)
@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=lambda s: s.name)
def test_ctrl_c_at_depth_lifts_to_the_travel_height(tmp_path, signum):
    """SIGINT (or SIGTERM: systemctl stop) while the probe dwells 2 mm below the surface (Z 5.5): with the paper
    profile it ends at the profile's travel height, safe height 10 above the surface (Z 15.5), above the
    program's own Z 8."""
    assert MARLIN is not None
    gcode = tmp_path / "press.gcode"
    gcode.write_text(
        "\n".join(["G90", "G92 X100 Y100 Z8", "G1 Z5.5 F300", "G1 Z3.5 F120", "G4 S3", "G1 Z8 F300", "M400"]) + "\n"
    )
    with FirmwareRelay(MARLIN / PLAIN) as relay:
        proc = subprocess.Popen(
            [sys.executable, "-m", "neatskin", "printer", "send", "--port", relay.path, "--no-progress"]
            + ["--boot-timeout-s", "0.1", "--profile", str(PROFILE), str(gcode)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
        assert relay.wait_for(lambda line: line.startswith(b"ok"), 20)  # the handshake
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any(b"G4 S3" in line for _, d, line in relay.transcript if d == ">"):
            time.sleep(0.05)
        time.sleep(1.5)  # the probe is at Z 3.5, two mm into the skin, dwelling (Z 8 -> 3.5 takes about 1.2 s)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        # where the firmware put the probe: M114 asked directly of the firmware, after the CLI left
        relay.send_raw(b"M400\nM114\n")
        assert relay.wait_for(lambda line: line.startswith(b"X:") and b"Count" in line, 10)
    position = [line for line in relay.replies() if line.startswith(b"X:")][-1]
    z_mm = float(position.split(b"Z:")[1].split()[0])
    assert z_mm == 15.5, (z_mm, err)
    assert "lifted the probe by 12.000 mm (Z was 3.5 mm, travel height 15.5 mm)" in err, err
    assert "the printer reports Z 15.5 mm" in err, err

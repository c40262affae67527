"""Hardware in the loop: `campaign run PROTOCOL --port PORT --daq simulated` drives a printer on a real port (the
simulated printer on a pty, or the real Marlin firmware behind a relay) and records the simulated skin along the
motion that crossed the serial line (neatskin.rig.hilrig, neatskin.sim.linetrack).

Oracles: every program line runs exactly once, in order (the printer's own record: the simulated printer's
executed list, the real firmware's `M111 S1` echo), the same program a dry run sends; the dataset validates; and
its resistances and forces equal, bit for bit, those of a dry run of the same protocol (the same moves, the same
seed). A printer that is not where its program put it stops the campaign (the negative control).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from neatskin.cli import main
from neatskin.errors import HardwareError
from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin.driver import MarlinDriver
from neatskin.marlin.replies import PROBE_TAG, Position
from neatskin.marlin.wirelog import read_wire_log
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.sim.linetrack import POSITION_TOLERANCE_MM, LineTracker
from neatskin.sim.printer import SimulatedPrinter
from neatskin.sim.realmarlin import ADVANCED_OK, FirmwareRelay, find_marlin_dir

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"
_FRAMED = re.compile(r"^N(\d+) (.*)\*\d+$")


def small_protocol(tmp_path: Path, *, count: int, repeats: int, fast_printer: bool = False) -> Path:
    """protocols/smoke.toml with fewer presses; for the real-time firmware, a 4 mm safe height (the descent still
    holds two sweeps of baseline before contact) and a low park, so the motion takes seconds, not tens of them."""
    text = (PROTOCOLS / "smoke.toml").read_text()
    printer = PROTOCOLS / "printers" / "paper.toml"
    if fast_printer:
        profile = printer.read_text()
        for old, new in [("safe_height_mm = 10.0", "safe_height_mm = 4.0"), ("z_mm = 60.0", "z_mm = 8.0")]:
            assert old in profile, old
            profile = profile.replace(old, new)
        printer = tmp_path / "fast-printer.toml"
        printer.write_text(profile)
    changes = [
        ("count = 6", f"count = {count}"),
        ("repeats = 2", f"repeats = {repeats}"),
        ('"skins/', f'"{PROTOCOLS}/skins/'),
        ('"wiring/', f'"{PROTOCOLS}/wiring/'),
        ('"printers/paper.toml"', f'"{printer}"'),
    ]
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / "small.toml"
    path.write_text(text)
    return path


def sent_commands(wire_log: Path) -> list[tuple[int, str]]:
    """(line number, command) of every framed line the host wrote, in order."""
    out = []
    for direction, data in read_wire_log(wire_log):
        if direction != ">":
            continue
        for raw in data.decode("ascii").splitlines():
            match = _FRAMED.match(raw.strip())
            if match:
                out.append((int(match.group(1)), match.group(2)))
    return out


def program_of(commands: list[tuple[int, str]]) -> list[str]:
    """The program's commands: without the session's (M110 line resets), the tracker's M114 and the probes."""
    return [c for _, c in commands if c != "M114" and not c.startswith("M110") and PROBE_TAG not in c]


def signals(folder: Path) -> pd.DataFrame:
    table = pd.read_parquet(folder / "presses.parquet").sort_values("press_id").reset_index(drop=True)
    return table[[c for c in table.columns if c.startswith(("R_ohm", "dR_ohm", "fsr_"))]]


def dry_run(protocol: Path, out: Path) -> None:
    assert main(["campaign", "run", str(protocol), "--dry-run", "--out", str(out), "--no-report", "-q"]) == 0


def assert_simulated_daq(folder: Path) -> None:
    rig = json.loads((folder / "manifest.json").read_text())["rig"]
    assert rig["kind"] == "real" and rig["daq"] == "simulated" and rig["skin"]["simulated"] is True
    metadata = pq.read_schema(folder / "presses.parquet").metadata
    assert json.loads(metadata[b"neatskin.rig"]) == "real"
    assert json.loads(metadata[b"neatskin.daq"]) == "simulated"


def test_simulated_printer_reached_through_port(tmp_path):
    protocol = small_protocol(tmp_path, count=3, repeats=1)
    printer = SimulatedPrinter(load_printer_profile(PROTOCOLS / "printers" / "paper.toml"), advanced_ok=True)
    port = printer.start_pty()
    try:
        out = tmp_path / "hil"
        argv = ["campaign", "run", str(protocol), "--port", port, "--daq", "simulated", "--out", str(out)]
        assert main([*argv, "--no-report", "-q", "--connect-timeout-s", "2"]) == 0
        executed = printer.executed
    finally:
        printer.stop()
    assert len(pd.read_parquet(out / "presses.parquet")) == 3
    assert_simulated_daq(out)
    assert main(["dataset", "validate", str(out)]) == 0
    # exactly once, in order: the line numbers the printer ran are 0, 1, 2, ... with none twice
    numbers = [n for n, _ in executed if n is not None]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers)))
    assert [c for _, c in executed] == [c for _, c in sent_commands(out / "wire.log")]
    # one M114 after every batch ending in M400 once homed: the preamble, and each press's phases and hold
    assert sum(c == "M114" for _, c in executed) == 1 + 3 * 5
    # the same program as a dry run, and bit for bit the same signals
    dry = tmp_path / "dry"
    dry_run(protocol, dry)
    assert program_of(executed) == program_of(sent_commands(dry / "wire.log"))
    pd.testing.assert_frame_equal(signals(out), signals(dry))


class _OffPrinter:
    """A driver whose printer acknowledges everything and reports (M114) a fixed position."""

    def __init__(self, reported_mm: tuple[float, float, float]) -> None:
        self.reported_mm, self.sent = reported_mm, []

    def send_lines(self, lines, *, source="<lines>"):
        self.sent.append(list(lines))
        return len(self.sent[-1])

    def position(self) -> Position:
        return Position(*self.reported_mm)


def test_a_printer_not_where_its_program_put_it_stops_the_campaign():
    profile = load_printer_profile(PROTOCOLS / "printers" / "paper.toml")
    driver = _OffPrinter((0.0, 0.0, 5.0))
    tracker = LineTracker(driver, profile)
    tracker.send_lines(["G90", "G28", "M400"], source="preamble")  # stock Marlin's G28 ends at Z 5: so does the shadow
    assert tracker.commanded_mm() == (0.0, 0.0, 5.0) and tracker.homing_corrections == []
    driver.reported_mm = (0.0, 0.0, 10.0)  # a printer built with Z_AFTER_HOMING 10: after a G28 its report is followed
    tracker.send_lines(["G28", "M400"], source="re-home")
    assert tracker.commanded_mm() == (0.0, 0.0, 10.0)
    assert tracker.homing_corrections == [((0.0, 0.0, 5.0), (0.0, 0.0, 10.0))]
    driver.reported_mm = (50.0, 60.0, 10.0 + POSITION_TOLERANCE_MM / 2)  # within M114's rounding: accepted
    tracker.send_lines(["G0 X50 Y60 F6000", "M400"], source="travel")
    driver.reported_mm = (50.0, 60.0, 10.0)  # commanded to Z 2, the printer stayed at Z 10
    with pytest.raises(HardwareError, match=r"reports X50.00 Y60.00 Z10.00 but its program put the probe at .*Z2\.000"):
        tracker.send_lines(["G1 Z2 F120", "M400"], source="press 0 press")
    assert driver.sent[-1] == ["G1 Z2 F120", "M400"]  # the printer got the batch once; nothing was resent


MARLIN = find_marlin_dir(REPO)


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.skipif(MARLIN is None, reason="the real firmware is absent: no shared/marlin beside the repository")
def test_real_firmware_with_the_simulated_daq(tmp_path):
    """Real time: the firmware's G28 alone takes ~45 s on its simulated board (measured, loaded machine)."""
    assert MARLIN is not None
    protocol = small_protocol(tmp_path, count=2, repeats=1, fast_printer=True)
    out = tmp_path / "hil"
    with FirmwareRelay(MARLIN / ADVANCED_OK) as relay:
        session = MarlinDriver.open(relay.path)
        session.connect()
        session.send("M111 S1")  # the firmware echoes every command it runs from now on: the oracle
        session.close()
        result = run_campaign(
            load_protocol(protocol),
            out,
            dry_run=False,
            port=relay.path,
            daq_kind="simulated",
            progress=False,
            report=False,
            connect_timeout_s=3.0,
        )
        echoed = [(n, c) for n, c in relay.executed() if PROBE_TAG not in c]
    assert (result.completed, result.flagged) == (2, 0)
    assert_simulated_daq(out)
    assert main(["dataset", "validate", str(out)]) == 0
    campaign = echoed[
        [c for _, c in echoed].index("M110 N0") :
    ]  # the campaign's session: the echo began after the set-up's
    numbers = [n for n, _ in campaign]
    assert numbers == list(range(len(numbers)))  # each line once, in order, as the firmware ran it
    assert [c for _, c in campaign] == [c for _, c in sent_commands(out / "wire.log") if PROBE_TAG not in c]
    dry = tmp_path / "dry"
    dry_run(protocol, dry)
    assert program_of(campaign) == program_of(sent_commands(dry / "wire.log"))
    pd.testing.assert_frame_equal(signals(out), signals(dry))


def test_resume_keeps_the_simulated_daq(tmp_path):
    """An interrupted hardware-in-the-loop campaign resumes with the DAQ it recorded (not the NI default) and
    ends with what an uninterrupted dry run records."""
    protocol = small_protocol(tmp_path, count=3, repeats=1)
    printer = SimulatedPrinter(load_printer_profile(PROTOCOLS / "printers" / "paper.toml"), advanced_ok=True)
    port = printer.start_pty()
    out = tmp_path / "hil"
    try:
        first = run_campaign(
            load_protocol(protocol), out, dry_run=False, port=port, daq_kind="simulated", progress=False, limit=1
        )
        assert first.completed == 1
        argv = ["campaign", "resume", str(out), "--port", port, "--no-report", "-q"]
        assert main(argv) == 0
    finally:
        printer.stop()
    assert_simulated_daq(out)
    assert main(["dataset", "validate", str(out)]) == 0
    dry = tmp_path / "dry"
    dry_run(protocol, dry)
    pd.testing.assert_frame_equal(signals(out), signals(dry))

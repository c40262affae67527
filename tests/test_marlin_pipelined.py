"""The dry run's press loop with lines pipelined (`ok N P B` and up to 4 in flight), beside one line in flight.

What a dry run may switch on (rig/dryrig: `SimulatedPrinter(..., advanced_ok=True)` and
`DriverConfig(..., max_in_flight=4)`) must change nothing it records: every command runs exactly
once and in order over a noisy line, each send_lines returns only after its last line ran, and
the printer's clock at every return (what the recorder reads as its marks) is the same as with
one line in flight.
"""

from __future__ import annotations

import pytest

from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.marlin.replies import PROBE_TAG
from neatskin.sim.faults import FaultConfig
from neatskin.sim.printer import sim_printer_for_tests

pytestmark = pytest.mark.slow

PREAMBLE = ("G21", "G90", "M211 S1", "G28", "M400")


def press_batches(i: int) -> list[tuple[str, ...]]:
    """The paper press's five send_lines calls (rig.runner: travel, descend, press, hold, lift)."""
    x, y = 100.0 + (i * 7.123) % 40, 90.0 + (i * 13.77) % 30
    return [
        (f"M118 E1 NS press={i} phase=travel", "G0 Z15.5 F300", f"G0 X{x:.3f} Y{y:.3f} F6000", "M400"),
        (f"M118 E1 NS press={i} phase=descend", "G1 Z5.5 F300", "M400"),
        (f"M118 E1 NS press={i} phase=press", "G1 Z2 F120", "M400"),
        ("G4 P1200", "M400"),
        (f"M118 E1 NS press={i} phase=lift", "G0 Z15.5 F300", "M400"),
    ]


def run_presses(n: int, *, pipelined: bool, faults: FaultConfig = FaultConfig()):
    printer = sim_printer_for_tests(seed=3, faults=faults, advanced_ok=pipelined)
    config = DriverConfig(
        boot_timeout_s=0.1,
        min_timeout_s=0.2,
        poll_s=0.01,
        probe_attempts=8,
        max_resends=40,
        motion_time_scale=0.0,
        max_in_flight=4 if pipelined else 1,
    )
    driver = MarlinDriver.open(printer.start_pty(), config=config)
    clocks, late = [], []
    try:
        driver.connect()
        driver.send_lines(PREAMBLE)
        sent = len(PREAMBLE)
        for i in range(n):
            for batch in press_batches(i):
                driver.send_lines(batch)
                sent += len(batch)
                ran = [text for _, text in printer.executed if not text.startswith("M110") and PROBE_TAG not in text]
                if printer.executed_count - (len(printer.executed) - len(ran)) < sent:
                    late.append(batch)  # returned before every line of the batch ran
                clocks.append(printer.now_s())
        stats = driver.stats
    finally:
        driver.close()
        printer.stop()
    executed = [text for _, text in printer.executed if not text.startswith("M110") and PROBE_TAG not in text]
    return executed, clocks, late, stats


def expected_program(n: int) -> list[str]:
    return [*PREAMBLE, *(line for i in range(n) for batch in press_batches(i) for line in batch)]


@pytest.mark.timeout(120)
def test_pipelined_presses_record_what_one_line_in_flight_records():
    n = 40
    executed, clocks, late, stats = run_presses(n, pipelined=True)
    executed_1, clocks_1, late_1, _ = run_presses(n, pipelined=False)
    assert executed == executed_1 == expected_program(n)
    assert late == late_1 == []
    assert clocks == clocks_1  # the recorder's marks: bit for bit
    assert stats["max_in_flight"] >= 3


@pytest.mark.timeout(180)
@pytest.mark.parametrize("preset", ["realistic", "extreme"])
def test_pipelined_presses_over_a_noisy_line_run_every_command_once_in_order(preset):
    n = 60 if preset == "realistic" else 15
    executed, _, late, stats = run_presses(n, pipelined=True, faults=FaultConfig.preset(preset))
    assert executed == expected_program(n)
    assert late == []  # a duplicated or lost `ok` never lets a batch return before its M400 ran
    if preset == "extreme":
        assert stats["lines_resent"] > 5 and stats["max_in_flight"] >= 3

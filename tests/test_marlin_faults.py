"""Fault injection: thousands of commands through the simulated printer on a real pty.

Every command must be executed exactly once and in order, whatever the line does; when the
printer resets or the port dies the driver stops with an error naming the last line the
printer acknowledged, and the printer's log is a prefix of the program ending at that line
(or one line past it: a line executed whose `ok` never came back).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neatskin.marlin import errors as E
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.marlin.replies import PROBE_TAG
from neatskin.sim.faults import FaultConfig
from neatskin.sim.printer import sim_printer_for_tests

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

QUICK = DriverConfig(
    boot_timeout_s=0.1,
    min_timeout_s=0.12,
    busy_extension_s=0.5,
    poll_s=0.01,
    probe_attempts=8,
    max_resends=40,
    motion_time_scale=0.0,
)


def program(n: int, seed: int) -> list[str]:
    """n unique commands: moves inside the bed, with echoes, dwells, syncs and queries between them."""
    rng = np.random.default_rng(seed)
    lines = []
    for i in range(n):
        kind = i % 10
        if kind == 3:
            lines.append(f"M118 E1 NS press={i} phase=press")
        elif kind == 6:
            lines.append(f"G4 P{i % 7}")
        elif kind == 9:
            lines.append(f"M400 ; sync {i}")
        else:
            x, y = rng.uniform(20, 200, 2)
            lines.append(f"G1 X{x:.3f} Y{y:.3f} Z{5 + i % 3} F{6000 + i}")
    return lines


def executed_program(sim) -> list[str]:
    """The printer's own log without the driver's handshake and lost-ok probes: `M118 E1 NS n`, or `M114` where
    the driver fell back to it (a fault ate an M118 probe's echo, and the firmware looked like one that answers
    M118 with a bare ok). The programs here hold no M114 of their own."""
    return [
        text
        for n, text in sim.executed
        if not text.startswith("M110") and PROBE_TAG not in text and text not in ("G28", "M114")
    ]


def run(faults: FaultConfig, n: int, seed: int, config: DriverConfig = QUICK, **sim_kw):
    sim = sim_printer_for_tests(seed=seed, faults=faults, **sim_kw)
    path = sim.start_pty()
    driver = MarlinDriver(serial.serial_for_url(path, do_not_open=True), config=config)
    lines = program(n, seed)
    error = None
    try:
        driver.connect()
        driver.send("G28")
        driver.send_lines(lines)
    except E.MarlinError as exc:
        error = exc
    finally:
        driver.close()
        sim.stop()
    expected = [line.split(";")[0].strip() for line in lines]
    return sim, driver, expected, error


@pytest.mark.timeout(120)
@pytest.mark.parametrize("seed", [1])
def test_realistic_rates_every_command_exactly_once_in_order(seed):
    faults = FaultConfig.preset("realistic")
    sim, driver, expected, error = run(faults, 3000, seed)
    assert error is None, error
    assert executed_program(sim) == expected
    assert driver.stats["lines_resent"] + driver.stats["probes"] > 0  # faults really happened


@pytest.mark.timeout(150)
@pytest.mark.parametrize(
    ("variant", "n"),
    [
        ({}, 800),
        ({"marlin_version": "2.0"}, 200),  # a repeated line is answered with an error, not dropped
        ({"ok_after_resend": True, "marlin_version": "2.0"}, 200),  # Marlin 1.x: `Resend:` then `ok`
        ({"advanced_ok": True}, 200),  # `ok N.. P.. B..`
    ],
)
def test_extreme_rates_every_command_exactly_once_in_order(variant, n):
    faults = FaultConfig.preset("extreme")
    sim, driver, expected, error = run(faults, n, seed=7, **variant)
    assert error is None, error
    assert executed_program(sim) == expected
    stats = driver.stats
    assert stats["lines_resent"] > 20 and stats["probes"] > 10 and stats["busy"] > 20


@pytest.mark.timeout(120)
@pytest.mark.parametrize("preset", ["realistic", "extreme"])
def test_pipelined_with_advanced_ok_every_command_exactly_once_in_order(preset):
    config = replace(QUICK, max_in_flight=4)
    sim, driver, expected, error = run(
        FaultConfig.preset(preset), 1000 if preset == "realistic" else 300, seed=9, config=config, advanced_ok=True
    )
    assert error is None, error
    assert executed_program(sim) == expected
    assert driver.stats["max_in_flight"] >= 3


def _check_prefix(sim, expected, error):
    done = executed_program(sim)
    assert done == expected[: len(done)], "executed lines are not a prefix of the program"
    # the program repeats commands (M400, G4): the acknowledged one is the last occurrence within what ran
    acked = max(i for i, command in enumerate(expected[: len(done) + 1]) if command == error.last_command)
    assert acked <= len(done) - 1 <= acked + 1
    return done


@pytest.mark.timeout(120)
def test_reset_mid_campaign_stops_with_the_last_acknowledged_line():
    faults = FaultConfig.parse("realistic,reset_after=700")
    sim, driver, expected, error = run(faults, 2000, seed=3)
    assert isinstance(error, E.PrinterReset), error
    done = _check_prefix(sim, expected, error)
    assert 690 <= len(done) <= 700
    assert "rebooted" in str(error) and f"N{error.last_line} {error.last_command!r}" in str(error)


@pytest.mark.timeout(120)
def test_silent_dead_printer_raises_no_answer():
    faults = FaultConfig.parse("realistic,dead_after=400")
    sim, driver, expected, error = run(faults, 1000, seed=4)
    assert isinstance(error, E.NoAnswer), error
    _check_prefix(sim, expected, error)


@pytest.mark.timeout(120)
def test_closed_port_raises_port_dead():
    faults = FaultConfig.parse("realistic,dead_after=300,dead_closes=1")
    sim, driver, expected, error = run(faults, 1000, seed=5)
    assert isinstance(error, (E.PortDead, E.NoAnswer)), error
    _check_prefix(sim, expected, error)


def test_fault_spec_parsing_and_errors():
    assert FaultConfig.parse("realistic,reset_after=5").reset_after == 5
    assert FaultConfig.parse("realistic,reset_after=5").corrupt == FaultConfig.preset("realistic").corrupt
    assert FaultConfig.parse("corrupt=0.5,dead_closes=yes") == FaultConfig(corrupt=0.5, dead_closes=True)
    from neatskin.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown fault 'noise'"):
        FaultConfig.parse("noise=0.1")
    with pytest.raises(ConfigError, match="not a probability"):
        FaultConfig.parse("corrupt=2")


@pytest.mark.timeout(120)
@settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    seed=st.integers(0, 2**16),
    corrupt=st.floats(0, 0.1),
    drop_line=st.floats(0, 0.05),
    drop_ok=st.floats(0, 0.05),
    duplicate=st.floats(0, 0.05),
    busy_storm=st.floats(0, 0.05),
    version=st.sampled_from(
        [{}, {"marlin_version": "2.0"}, {"advanced_ok": True}, {"marlin_version": "2.0", "ok_after_resend": True}]
    ),
)
def test_any_fault_mix_in_process_runs_each_command_once(
    seed, corrupt, drop_line, drop_ok, duplicate, busy_storm, version
):
    faults = FaultConfig(
        corrupt=corrupt, drop_line=drop_line, drop_ok=drop_ok, duplicate=duplicate, busy_storm=busy_storm
    )
    sim = sim_printer_for_tests(seed=seed, faults=faults, **version)
    driver = MarlinDriver(sim.serial(), config=QUICK)
    lines = program(100, seed)
    try:
        driver.connect()
        driver.send("G28")
        driver.send_lines(lines)
    finally:
        driver.close()
    assert executed_program(sim) == [line.split(";")[0].strip() for line in lines]

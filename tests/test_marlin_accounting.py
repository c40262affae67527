"""The driver follows the firmware's own accounting: B of `ok N.. P.. B..`, the profile's RX buffer, the probe
counted against the cap, and a firmware that answers the M118 probe with a bare `ok` (fallback to M114).

Sans-IO tests drive LineProtocol with exact bytes and a clock that is a number; the 64-byte peer is the
simulated printer with a 64-byte receive ring (bytes past it are lost, `rx_overflow_bytes`), on a pty.
"""

from __future__ import annotations

import dataclasses
import functools

import pytest
from linestate_outcomes import done, ok, replies

from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin.driver import MarlinDriver
from neatskin.marlin.jobs import DriverConfig, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.marlin.replies import PROBE_TAG
from neatskin.sim.faults import FaultConfig
from neatskin.sim.printer import SimulatedPrinter

CONFIG = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, busy_extension_s=0.6, poll_s=0.01, max_in_flight=4)


def cs(n: int, command: str) -> bytes:
    body = f"N{n} {command}".encode()
    return body + b"*" + str(functools.reduce(lambda a, b: a ^ b, body, 0)).encode() + b"\n"


def connected(config: DriverConfig = CONFIG, **kwargs) -> LineProtocol:
    proto = LineProtocol(config, **kwargs)
    proto.start_session(0.0, boot_timeout_s=0)
    assert proto.data_to_send() == [b"N0 M110 N0*125\n"]
    proto.receive(b"ok N0 P15 B3\n", 0.01)
    return proto


def test_b_caps_the_lines_in_flight():
    proto = connected()
    jobs = [Job(f"M118 E1 t{i}") for i in range(8)]
    proto.submit(jobs, 1.0)
    # the handshake's `ok N0 P15 B3` named its line: three free slots, and max_in_flight 4 keeps one for a
    # lost-ok probe: three lines
    assert proto.data_to_send() == [cs(1, "M118 E1 t0"), cs(2, "M118 E1 t1"), cs(3, "M118 E1 t2")]
    proto.receive(b"ok N1 P15 B0\n", 1.1)  # the firmware's queue is full: nothing more goes out
    assert proto.data_to_send() == [] and proto.in_flight == 2
    proto.receive(b"ok N2 P15 B1\n", 1.2)  # one free slot and one line in flight: still nothing
    assert proto.data_to_send() == [] and proto.in_flight == 1
    proto.receive(b"ok N3 P15 B2\n", 1.3)
    assert proto.data_to_send() == [cs(4, "M118 E1 t3"), cs(5, "M118 E1 t4")]


def test_the_rx_budget_comes_from_the_profile_or_the_caller(protocols_dir):
    profile = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    assert LineProtocol(CONFIG, profile).rx_budget_bytes == 127
    small = dataclasses.replace(profile, rx_buffer_size=64)
    assert LineProtocol(CONFIG, small).rx_budget_bytes == 63
    assert LineProtocol(CONFIG, small, rx_buffer_size=256).rx_budget_bytes == 255
    proto = connected(rx_buffer_size=64)
    proto.submit([Job(f"M118 E1 tag number {i}") for i in range(6)], 1.0)
    # 29 bytes a line: a second fits in 63 bytes with the 16-byte margin for its framing, a third does not
    assert proto.data_to_send() == [cs(1, "M118 E1 tag number 0"), cs(2, "M118 E1 tag number 1")]


def test_the_lost_ok_probe_counts_against_the_cap():
    """The oldest line is overdue while two later lines are still due: the probe waits until it fits
    in the 63 bytes beside them (lines past their deadline have left the firmware's RX buffer)."""
    proto = connected(rx_buffer_size=64)
    proto.submit([Job("M118 E1 t0")], 1.0)
    assert proto.data_to_send() == [cs(1, "M118 E1 t0")]  # due at 1.4
    proto.submit([Job("M118 E1 t1"), Job("M118 E1 t2")], 1.2)
    assert proto.data_to_send() == [cs(2, "M118 E1 t1"), cs(3, "M118 E1 t2")]  # 17 bytes each, due at 1.6
    probe = cs(4, f"M118 E1 {PROBE_TAG} 4")
    assert 2 * 17 + len(probe) > 63
    proto.tick(1.4 + 1e-6)  # line 1's ok is lost: overdue, but a probe would overflow the buffer now
    assert proto.data_to_send() == [] and proto.stats["probes_deferred"] == 1
    proto.tick(1.6 + 1e-6)  # every line is past its deadline: the probe fits
    assert proto.data_to_send() == [probe]
    proto.receive(f"echo:{PROBE_TAG} 4\r\nok N4 P15 B3\n".encode(), 1.7)
    assert proto.in_flight == 0 and proto.stats["oks_recovered"] == 3
    assert proto.stats["max_bytes_in_flight"] <= 63


def test_a_bare_ok_to_the_m118_probe_falls_back_to_m114():
    """A firmware that answers `M118` with a bare ok and no echo: the batch completes on an M114 probe."""
    proto = connected(DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, confirm_batches=True))
    job, barrier = Job("G92 X1"), Job("", barrier=True)
    proto.submit([job, barrier], 1.0)
    assert proto.data_to_send() == [cs(1, "G92 X1")]
    proto.receive(b"ok\n", 1.1)
    assert done(proto, job) and proto.data_to_send() == [cs(2, f"M118 E1 {PROBE_TAG} 2")]
    proto.receive(b"ok\n", 1.2)  # no echo: a duplicate, or a firmware that does not echo M118
    assert not done(proto, barrier)
    proto.tick(1.2 + 0.4 + 1e-6)
    assert proto.data_to_send() == [cs(3, "M114")]  # the fallback probe
    proto.receive(b"X:1.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n", 1.7)
    assert ok(proto, barrier) and proto.failure is None
    assert proto.stats["probe_fallbacks"] == 1
    # from now on every confirming probe is an M114, and a caller's own M114 keeps its reply
    own, last = Job("M114"), Job("", barrier=True)
    proto.submit([own, last], 2.0)
    assert proto.data_to_send() == [cs(4, "M114")]
    proto.receive(b"X:1.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n", 2.1)
    assert replies(proto, own) == ["X:1.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"]
    assert proto.data_to_send() == [cs(5, "M114")]
    proto.receive(b"X:1.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n", 2.2)
    assert ok(proto, last)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_64_byte_peer_with_a_profile_saying_so_runs_every_line_once(protocols_dir, seed):
    """The simulated printer with a 64-byte receive ring (bytes past it are lost) and ADVANCED_OK, noisy
    (corrupted lines, lost oks), real-time motion; the driver pipelines up to 4 lines on the profile's 64."""
    profile = dataclasses.replace(load_printer_profile(protocols_dir / "printers" / "paper.toml"), rx_buffer_size=64)
    faults = FaultConfig(corrupt=0.03, drop_ok=0.03)
    printer = SimulatedPrinter(
        profile, seed=seed, faults=faults, advanced_ok=True, rx_buffer_size=64, time_mode="scaled", speed=50.0
    )
    program = ["G28", "M400"]
    for i in range(40):
        program += [f"M118 E1 NS press={i}", f"G1 X{100 + i % 7} Y{90 + i % 5} Z{5 + i % 3} F6000"]
    program += ["M400"]
    config = DriverConfig(
        boot_timeout_s=0.1,
        min_timeout_s=0.3,
        poll_s=0.01,
        max_in_flight=4,
        motion_time_scale=0.02,
        confirm_batches=True,
    )
    driver = MarlinDriver.open(printer.start_pty(), config=config, profile=profile)
    try:
        driver.connect()
        driver.send_lines(program)
        stats = dict(driver.stats)
    finally:
        driver.close()
        printer.stop()
    ran = [text for _, text in printer.executed if not text.startswith("M110") and PROBE_TAG not in text]
    assert ran == program  # every line once, in order: no fragment of a line ran
    assert printer.core.rx_overflow_bytes == 0
    assert stats["max_bytes_in_flight"] <= 63 and stats["max_in_flight"] <= 4
    assert stats["max_in_flight"] >= 2  # it did pipeline


def test_the_64_byte_ring_loses_what_does_not_fit(protocols_dir):
    """The negative control: the model itself drops bytes past the ring (a 100-byte burst into 64)."""
    profile = load_printer_profile(protocols_dir / "printers" / "paper.toml")
    printer = SimulatedPrinter(profile, rx_buffer_size=64)
    core = printer.core
    core.take_output()
    for _ in range(4):  # nothing runs between reads here: the command queue (BUFSIZE 4) is full
        core.receive(b"M118 E1 fill the command queue\n")
    burst = b"".join(cs(n, "M118 E1 a line of about thirty") for n in range(1, 5))  # 4 x 37 bytes
    core.receive(burst)
    assert core.rx_overflow_bytes == len(burst) - 63

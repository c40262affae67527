"""The clock seam: every time the Marlin host side reads is the injected clock's, and the reader sleeps until
the protocol's next deadline instead of polling.

The protocol's deadlines pass with a clock that is a number (no sleep, no thread); the wire log stamps
with the clocks it is given; both channels honour the write timeout; a pty channel's read wakes on
request; an idle driver's reader does not wake at all.
"""

from __future__ import annotations

import threading
import time

import pytest

from neatskin.marlin.driver import MarlinDriver
from neatskin.marlin.jobs import DriverConfig, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.marlin.replies import PROBE_TAG, frame
from neatskin.marlin.transport import FdChannel, SerialChannel
from neatskin.marlin.wirelog import WireLog, read_wire_log
from neatskin.sim.printer import sim_printer_for_tests
from neatskin.sim.pty import open_pty

CONFIG = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, ok_after_resend=False)


def test_next_deadline_follows_the_session_and_passes_with_the_fake_clock_alone():
    proto = LineProtocol(CONFIG)
    proto.start_session(10.0)
    assert proto.next_deadline() == 10.5  # the boot wait
    proto.receive(b"start\n", 10.1)
    assert proto.next_deadline() == pytest.approx(10.15)  # the banner settles for 50 ms
    proto.tick(10.15)
    assert proto.data_to_send() == [frame("M110 N0", 0)]
    assert proto.next_deadline() == pytest.approx(10.55)  # the M110's own deadline (before the 30 s connect cap)
    proto.receive(b"ok\n", 10.2)
    assert proto.next_deadline() is None  # nothing in flight, nothing queued: sleep until the printer talks
    proto.submit([Job("M118 E1 a")], 11.0)
    assert proto.data_to_send() == [frame("M118 E1 a", 1)]
    assert proto.next_deadline() == pytest.approx(11.4)
    proto.tick(11.4 - 1e-9)
    assert proto.data_to_send() == []  # not yet
    proto.tick(11.4)  # the deadline passes: the lost-ok probe goes out, from the number alone
    assert proto.data_to_send() == [frame(f"M118 E1 {PROBE_TAG} 2", 2)]
    proto.receive(b"Error:checksum mismatch, Last Line: 0\nResend: 1\n", 11.5)
    # a known Marlin-2 dialect replays at once (in the same call), and the replay has its own deadline
    assert proto.data_to_send() == [frame("M118 E1 a", 1), frame(f"M118 E1 {PROBE_TAG} 2", 2)]
    assert proto.next_deadline() == pytest.approx(11.9)


def test_a_drain_ends_by_the_fake_clock():
    proto = LineProtocol(CONFIG)
    proto.start_session(0.0, boot_timeout_s=0)
    proto.receive(b"ok\n", 0.01)
    proto.submit([Job("G4 S100")], 1.0)
    proto.drain(1.0, 5.0)
    assert not proto.drained and proto.next_deadline() == pytest.approx(6.0)  # before G4's own 100 s
    proto.tick(5.999)
    assert not proto.drained
    proto.tick(6.0)
    assert proto.drained and proto.drain_expired and proto.in_flight == 1


def test_the_wire_log_stamps_with_the_clocks_it_is_given(tmp_path):
    ticks = iter([100.0, 100.0, 101.25])
    log = WireLog(tmp_path / "w.log", clock=lambda: next(ticks), wall_ns=lambda: 1_700_000_000_123_456_789)
    log.write(">", b"N1 G28*18\n")
    log.close()
    lines = (tmp_path / "w.log").read_text().splitlines()
    assert lines[1] == "2023-11-14T22:13:20.123456Z     1.250000 > b'N1 G28*18\\n'"
    assert read_wire_log(tmp_path / "w.log")[-1] == (">", b"N1 G28*18\n")


class _SlowPort:
    """A pyserial-like port whose write times out (pyserial raises SerialTimeoutException)."""

    def __init__(self) -> None:
        self.write_timeout: float | None = None

    def write(self, data: bytes) -> int:
        import serial

        raise serial.SerialTimeoutException("Write timeout")


def test_the_write_timeout_is_honoured_on_both_channels():
    port = _SlowPort()
    with pytest.raises(TimeoutError):
        SerialChannel(port).write(b"N1 G28*18\n", 1.5)  # type: ignore[arg-type]
    assert port.write_timeout == 1.5
    pair = open_pty()
    now = [0.0]

    def clock() -> float:  # each call a second later: the deadline passes without waiting
        now[0] += 1.0
        return now[0]

    try:
        import os

        os.set_blocking(pair.slave_fd, False)
        channel = FdChannel(pair.slave_fd, clock)
        with pytest.raises(TimeoutError):
            channel.write(b"x" * 1_000_000, 2.0)  # nobody reads the master: the pty fills up
        channel.close()
    finally:
        pair.close()


@pytest.mark.timeout(10)
def test_a_pty_read_without_deadline_wakes_on_request():
    pair = open_pty()
    channel = FdChannel(pair.slave_fd)
    try:
        threading.Timer(0.2, channel.wake).start()
        start = time.monotonic()
        assert channel.read(None) == b""  # no deadline: it would wait for ever, the wake ends it
        assert time.monotonic() - start < 5
    finally:
        channel.close()
        pair.close()


@pytest.mark.timeout(20)
def test_an_idle_driver_does_not_poll():
    printer = sim_printer_for_tests()
    driver = MarlinDriver.open(printer.start_pty(), config=DriverConfig(boot_timeout_s=0.1, motion_time_scale=0))
    try:
        driver.connect()
        driver.send("M118 E1 hello")
        before = driver.reader_wakeups
        time.sleep(0.5)  # at the old 20 ms poll: 25 wake-ups; now at most one per min_timeout_s (2 s)
        assert driver.reader_wakeups - before <= 1
        assert driver.send("M114")[0].startswith("X:")  # and a new command wakes it at once
    finally:
        driver.close()
        printer.stop()


@pytest.mark.timeout(30)
def test_a_caller_reads_its_own_replies_and_the_reader_takes_over_when_it_is_gone():
    """A round trip wakes the printer's side and the blocked caller, no reader thread in between: the caller
    takes the read while no one reads. The wire carries the same bytes; the reader reads again once idle."""
    printer = sim_printer_for_tests()
    driver = MarlinDriver.open(printer.start_pty(), config=DriverConfig(boot_timeout_s=0.1, motion_time_scale=0))
    try:
        driver.connect()
        driver.send("G28")
        time.sleep(0.05)
        before_reads, before_callers = driver.reader_wakeups, driver.caller_reads
        for i in range(30):
            assert driver.send(f"M118 E1 round {i}") == [f"echo:round {i}"]
        reads = driver.reader_wakeups - before_reads
        by_callers = driver.caller_reads - before_callers
        assert by_callers >= 30  # every reply was read by the caller waiting for it ...
        assert reads - by_callers <= 1  # ... the reader thread stood by (one read it was in already, at most)
        assert driver.stats["lines_sent"] == 32  # M110, G28 and the 30 lines: nothing resent, nothing probed
        time.sleep(0.6)  # past READER_STANDBY_S: the reader reads the idle port again
        assert driver._link._reading and driver.caller_reads - before_callers == by_callers
        assert driver.send("M118 E1 after") == ["echo:after"]  # its read hands the reply over, as before
    finally:
        driver.close()
        printer.stop()


@pytest.mark.timeout(60)
def test_callers_on_two_threads_hand_the_read_to_each_other():
    """Two threads send at once: one reads for both, and when its job ends another waiting caller takes the read;
    each gets its own replies, in order, and every line goes out once."""
    printer = sim_printer_for_tests()
    driver = MarlinDriver.open(printer.start_pty(), config=DriverConfig(boot_timeout_s=0.1, motion_time_scale=0))
    replies: dict[str, list[list[str]]] = {"a": [], "b": []}
    errors: list[BaseException] = []

    def sender(name: str) -> None:
        try:
            for i in range(40):
                replies[name].append(driver.send(f"M118 E1 {name} {i}"))
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    try:
        driver.connect()
        threads = [threading.Thread(target=sender, args=(name,)) for name in ("a", "b")]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=30)
        assert not any(thread.is_alive() for thread in threads) and errors == []
        for name in ("a", "b"):
            assert replies[name] == [[f"echo:{name} {i}"] for i in range(40)]
        assert driver.stats["lines_sent"] == 81 and driver.stats["lines_resent"] == 0  # M110 and the 80 lines
        executed = [text for _, text in printer.executed if text.startswith("M118")]
        assert sorted(executed) == sorted(f"M118 E1 {name} {i}" for name in "ab" for i in range(40))
    finally:
        driver.close()
        printer.stop()

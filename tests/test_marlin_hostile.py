"""Hostile peers on a real pty: each ends in one named MarlinError after a bounded number of lines, and the
three resend dialects refusing a line twice still run every command exactly once and in order."""

from __future__ import annotations

from dataclasses import replace

import pytest

from neatskin.marlin import errors as E
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.sim.scripted import DialectFirmware, FirmwareOnPty

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

# motion_time_scale=0: these peers take no time to move, so deadlines need no motion allowance
QUICK = DriverConfig(
    boot_timeout_s=0.3, min_timeout_s=0.3, poll_s=0.01, probe_attempts=2, connect_attempts=6, motion_time_scale=0.0
)
PROGRAM = [f"G1 X{i} Y{2 * i} F6000" for i in range(1, 13)]


@pytest.fixture
def serve():
    made = []

    def start(firmware: DialectFirmware, config: DriverConfig = QUICK, **kw):
        peer = FirmwareOnPty(firmware, **kw)
        driver = MarlinDriver.open(peer.path, config=config)
        made.append((peer, driver))
        return peer, driver

    yield start
    for peer, driver in made:
        driver.close()
        peer.close()


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    ("mode", "error", "max_lines"),
    [
        ("start", E.ConnectFailed, 6),  # a boot loop: 2.28 million M110 in 300 s before the cap
        ("resend0", E.ConnectFailed, 6),  # `Resend: 0` for ever: one M110 every 20 ms before the cap
        ("garbage", E.NoAnswer, 3),
        ("silent", E.NoAnswer, 3),
    ],
)
def test_hostile_peer_at_connect_ends_in_one_named_error(serve, mode, error, max_lines):
    firmware = DialectFirmware(mode=mode)
    peer, driver = serve(firmware)
    with pytest.raises(error) as info:
        driver.connect()
    assert isinstance(info.value, E.MarlinError)
    assert 1 <= firmware.lines_received <= max_lines
    assert "no line of this session was acknowledged" in str(info.value)


@pytest.mark.timeout(30)
def test_a_peer_acknowledging_lines_never_sent_fails_the_handshake_out_of_step(serve):
    """`ok N<n+1000>` to every line: not one of them is the handshake's own ok (N0): after the M110's retries,
    one OutOfStep naming the ok's line; no session, nothing else sent."""
    firmware = DialectFirmware(mode="ahead")
    peer, driver = serve(firmware)
    with pytest.raises(E.OutOfStep) as info:
        driver.connect()
    assert "every `ok` named another line (the latest N1000), never the handshake's" in str(info.value)
    assert firmware.lines_received == 1 + QUICK.probe_attempts  # the M110 and its retries, nothing more


@pytest.mark.timeout(30)
@pytest.mark.parametrize("mode", ["start", "garbage", "silent", "resend0", "ahead"])
def test_peer_turning_hostile_mid_stream_ends_in_one_named_error(serve, mode):
    firmware = DialectFirmware()
    peer, driver = serve(firmware)
    driver.connect()
    driver.send_lines(PROGRAM[:3])
    firmware.mode = mode
    with pytest.raises(E.MarlinError) as info:
        driver.send_lines(PROGRAM[3:])
    expected = {
        "start": E.PrinterReset,
        "garbage": E.NoAnswer,
        "silent": E.NoAnswer,
        "resend0": E.NoAnswer,
        "ahead": E.OutOfStep,  # `ok N1004` for line N4: out of step at once, N4 not taken as done
    }
    assert isinstance(info.value, expected[mode]), info.value
    assert info.value.last_line == 3 and info.value.last_command == PROGRAM[2]
    if mode == "start":  # the fix says what a user of the CLI does (before: "call reconnect()", Python only)
        assert "run the command again (a campaign: neatskin campaign resume FOLDER, which homes first" in str(
            info.value
        )
    assert firmware.lines_received <= 1 + 3 + QUICK.max_resends + 2  # bounded: no flood


@pytest.mark.timeout(30)
def test_double_ok_in_separate_reads_cannot_end_a_confirmed_send_early(serve):
    config = replace(QUICK, confirm_batches=True)
    firmware = DialectFirmware(mode="double_ok")
    peer, driver = serve(firmware, split_s=0.005, config=config)
    driver.connect()
    program = [f"G1 X{i}" for i in range(1, 60)]
    assert driver.send_lines(program) == 59
    ran = [c for c in firmware.executed if "neatskin-probe" not in c]  # read as soon as send_lines returned
    assert ran == ["M110 N0", *program]
    assert driver.stats["stray_oks"] > 0


@pytest.mark.timeout(30)
def test_double_ok_from_a_peer_that_cannot_echo_confirms_with_m114(serve):
    """It answers M118 with a bare ok (no echo): the confirming probe falls back to M114, whose position
    (here on the `ok` line, OctoPrint's form) the peer prints only after every line before it ran.
    (Before the fallback this ended in NoAnswer after a complete send; issue 24.)"""
    config = replace(QUICK, confirm_batches=True)

    class NoEcho(DialectFirmware):
        def _line(self, text: str) -> bytes:
            if "M118" in text:
                self.last_n += 1
                return self._ok()
            return super()._line(text)

    firmware = NoEcho(mode="double_ok")
    peer, driver = serve(firmware, split_s=0.005, config=config)
    driver.connect()
    program = [f"G1 X{i}" for i in range(1, 30)]
    assert driver.send_lines(program) == 29
    assert driver.stats["probe_fallbacks"] == 1
    assert [c for c in firmware.executed if c.startswith("G1")] == program
    assert firmware.lines_received <= 1 + 29 + 1 + 2 + 3


@pytest.mark.timeout(30)
@pytest.mark.parametrize("dialect", ["marlin1", "marlin2", "repetier"])
def test_dialect_refusing_one_line_twice_runs_every_command_once_in_order(serve, dialect):
    firmware = DialectFirmware(dialect, reject={4: 2, 9: 2})
    peer, driver = serve(firmware)
    driver.connect()
    assert driver.send_lines(PROGRAM) == 12
    assert firmware.executed == ["M110 N0", *PROGRAM]
    assert driver.stats["lines_resent"] == 4
    assert driver.send("M105") == ["T:25.00 /0.00 B:24.00 /0.00"]
    position = driver.position()  # OctoPrint's `ok X:.. Y:.. Z:..`
    assert (position.x_mm, position.y_mm, position.z_mm) == (1.0, 2.0, 3.0)


@pytest.mark.timeout(30)
def test_the_port_is_exclusive(serve):
    firmware = DialectFirmware()
    peer, driver = serve(firmware)
    driver.connect()
    second = MarlinDriver.open(peer.path, config=QUICK)
    with pytest.raises(E.PortBusy) as info:
        second.connect()
    assert "in use" in str(info.value) and peer.path in str(info.value)
    second.close()
    driver.send("M400")  # the first session is untouched
    assert firmware.executed[-1] == "M400"


@pytest.mark.timeout(30)
def test_a_failing_wire_log_is_named_as_such_not_as_a_dead_port(serve, tmp_path):
    import errno

    peer = FirmwareOnPty(DialectFirmware())
    try:
        with pytest.raises(E.WireLogFailed, match="/dev/full"):
            MarlinDriver.open(peer.path, config=QUICK, wire_log="/dev/full").connect()
        driver = MarlinDriver.open(peer.path, config=QUICK, wire_log=tmp_path / "wire.log")
        driver.connect()
        driver.send("G28")

        def full(direction: str, data: bytes) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

        driver._link._wire.write = full  # the disk fills up in mid-session
        with pytest.raises(E.WireLogFailed) as info:
            driver.send("M400")
        assert "No space left" in str(info.value) and info.value.last_command == "G28"
        assert peer.firmware.executed == ["M110 N0", "G28"]  # nothing went out unlogged
        driver.close()
    finally:
        peer.close()

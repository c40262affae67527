"""Byte-level protocol tests of MarlinDriver against a scripted Marlin peer on a real pty.

Each test states the exact lines the driver must write (line numbers, checksums) and the
replies Marlin gives, in the manner of PyMeasure's expected_protocol.
"""

from __future__ import annotations

import functools
import os

import pytest
import serial

from neatskin.errors import HardwareError
from neatskin.marlin import errors as E
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.marlin.wirelog import read_wire_log
from neatskin.sim.scripted import ScriptedPeer

FAST = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, busy_extension_s=0.6, poll_s=0.01)


def cs(n: int, command: str) -> bytes:
    """The expected framed line, computed here independently of the driver."""
    body = f"N{n} {command}".encode()
    return body + b"*" + str(functools.reduce(lambda a, b: a ^ b, body, 0)).encode() + b"\n"


BOOT = (None, b"start\necho:Marlin 2.1.2.4\necho: Last Updated: 2024-01-01\n")
HELLO = (b"N0 M110 N0*125\n", b"ok\n")


@pytest.fixture
def run():
    made = []

    def start(script, config=FAST, wire_log=None, **peer_kw):
        peer = ScriptedPeer(script, **peer_kw)
        driver = MarlinDriver(serial.serial_for_url(peer.path, do_not_open=True), config=config, wire_log=wire_log)
        made.append((peer, driver))
        return peer, driver

    yield start
    for peer, driver in made:
        driver.close()
        peer.close()


@pytest.mark.timeout(20)
def test_literal_framing_and_normal_exchange(run, tmp_path):
    log = tmp_path / "wire.log"
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (b"N1 G28*18\n", b"echo:busy: processing\nok\n"),
            (b"N2 G1 X10 Y20 F3000*77\n", b"ok\n"),
            (b"N3 M114*36\n", b"X:10.00 Y:20.00 Z:0.00 E:0.00 Count X:800 Y:1600 Z:0\nok\n"),
            (b"N4 M400*35\n", b"ok\n"),
        ],
        wire_log=log,
    )
    driver.connect()
    assert driver.send("G28") == []
    assert driver.send("G1 X10 Y20 F3000 ; travel") == []
    pos = driver.position()
    assert (pos.x_mm, pos.y_mm, pos.z_mm, pos.count) == (10.0, 20.0, 0.0, (800, 1600, 0))
    driver.sync()
    peer.check()
    assert peer.extra_lines() == []
    assert driver.last_acknowledged == (4, "M400")
    sent = [data for d, data in read_wire_log(log) if d == ">"]
    assert sent == [b"N0 M110 N0*125\n", b"N1 G28*18\n", b"N2 G1 X10 Y20 F3000*77\n", b"N3 M114*36\n", b"N4 M400*35\n"]
    received = b"".join(data for d, data in read_wire_log(log) if d == "<")
    assert b"X:10.00 Y:20.00" in received and received.endswith(b"ok\n")


@pytest.mark.timeout(20)
@pytest.mark.parametrize(
    "error",
    [
        b"Error:checksum mismatch, Last Line: 1\n",
        b"Error:Line Number is not Last Line Number+1, Last Line: 1\n",
        b"Error:No Checksum with line number, Last Line: 1\n",
    ],
)
def test_each_communication_error_is_replayed_once(run, error):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "G1 X5"), error + b"Resend: 2\n"),
            (cs(2, "G1 X5"), b"ok\n"),
            (cs(3, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("G1 X5")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["lines_resent"] == 1


@pytest.mark.timeout(20)
def test_resend_followed_by_ok_old_marlin_does_not_acknowledge_the_replayed_line(run):
    # Marlin 1.x: "Resend: 2" then "ok"; that ok must not count for the replayed N2.
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "G1 X5"), b"Error:checksum mismatch, Last Line: 1\nResend: 2\nok\n"),
            (cs(2, "G1 X5"), [0.3, b"ok\n"]),
            (cs(3, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("G1 X5")
    assert driver.stats["oks_swallowed"] == 1
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []


@pytest.mark.timeout(20)
def test_rs_short_form_and_resend_without_error_line(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "M105"), b"rs 1\n"),
            (cs(1, "M105"), b"ok T:25.00 /0.00\n"),
        ]
    )
    driver.connect()
    assert driver.send("M105") == ["T:25.00 /0.00"]  # data on the ok line is kept
    peer.check()


@pytest.mark.timeout(20)
def test_duplicate_resend_is_ignored(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "G1 X5"), b"Error:checksum mismatch, Last Line: 1\nResend: 2\nResend: 2\n"),
            (cs(2, "G1 X5"), [0.2, b"ok\n"]),
            (cs(3, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("G1 X5")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["duplicate_resends"] == 1


@pytest.mark.timeout(20)
def test_stale_resend_for_an_acknowledged_line_is_ignored(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "M114"), b"Resend: 1\nX:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    assert driver.position().x_mm == 0.0
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["stale_resends"] == 1


@pytest.mark.timeout(20)
def test_resend_loop_is_capped(run):
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, max_resends=3)
    noisy = b"Error:checksum mismatch, Last Line: 0\nResend: 1\n"
    peer, driver = run([BOOT, HELLO] + [(cs(1, "G28"), noisy)] * 4, config=config)
    driver.connect()
    with pytest.raises(E.ResendLoop) as info:
        driver.send("G28")
    assert "N1" in str(info.value) and "asked for 4 times" in str(info.value)
    assert isinstance(info.value, HardwareError)
    peer.check()
    assert peer.extra_lines() == []


@pytest.mark.timeout(20)
def test_busy_keepalives_extend_the_deadline_without_a_probe(run):
    busy = b"echo:busy: processing\n"
    # 1.2 s of keep-alives, three times FAST.min_timeout_s
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G4 P10"), [busy, 0.3, busy, 0.3, busy, 0.3, busy, 0.3, b"ok\n"]),
            (cs(2, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G4 P10")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["probes"] == 0 and driver.stats["busy"] == 4


@pytest.mark.timeout(20)
@pytest.mark.parametrize(
    "text",
    [
        b"Error:Printer halted. kill() called!\n",
        b"Error:Printer stopped due to errors. Fix the error and use M999 to restart. "
        b"(Temperature is reset. Set it after restarting)\n",
    ],
)
def test_halt_raises_names_last_line_and_sends_nothing_more(run, text):
    peer, driver = run([BOOT, HELLO, (cs(1, "G28"), b"ok\n"), (cs(2, "G1 X5"), text)])
    driver.connect()
    driver.send("G28")
    with pytest.raises(E.PrinterHalted) as info:
        driver.send("G1 X5")
    message = str(info.value)
    assert info.value.last_line == 1 and info.value.last_command == "G28"
    assert "N1 'G28'" in message and "state is unknown" in message
    with pytest.raises(E.PrinterHalted):
        driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    driver.emergency_stop()  # M112 is still allowed
    assert peer.extra_lines() == [b"M112\n"]


@pytest.mark.timeout(20)
def test_start_in_mid_session_is_a_reset_and_reconnect_starts_over(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "G1 X5"), b"start\necho:Marlin 2.1.2.4\n"),
            HELLO,
            (cs(1, "M105"), b"ok T:25.0 /0.0\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    with pytest.raises(E.PrinterReset) as info:
        driver.send("G1 X5")
    assert info.value.last_line == 1
    driver.reconnect(boot_timeout_s=0.1)
    driver.send("M105")
    peer.check()
    assert peer.extra_lines() == []


@pytest.mark.timeout(20)
def test_lost_ok_is_recovered_by_probe_without_sending_the_line_twice(run):
    probe = "M118 E1 neatskin-probe 3"
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "M105"), b""),  # executed, but its ok is lost
            (cs(3, probe), b"echo:neatskin-probe 3\nok\n"),
            (cs(4, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("M105")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["probes"] == 1 and driver.stats["oks_recovered"] == 1


@pytest.mark.timeout(20)
def test_lost_line_is_replayed_after_the_probe_is_refused(run):
    probe = "M118 E1 neatskin-probe 3"
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "M105"), b""),  # the line never reached the firmware
            (cs(3, probe), b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\n"),
            (cs(2, "M105"), b"ok\n"),
            (cs(3, probe), b"echo:neatskin-probe 3\nok\n"),
            (cs(4, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("M105")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []


@pytest.mark.timeout(20)
def test_late_ok_during_probe_is_counted_once(run):
    probe = "M118 E1 neatskin-probe 3"
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "G4 P1"), b""),  # a command that outlives its deadline
            (cs(3, probe), b"ok\necho:neatskin-probe 3\nok\n"),
            (cs(4, "M400"), b"ok\n"),
        ]
    )
    driver.connect()
    driver.send("G28")
    driver.send("G4 P1")
    driver.send("M400")
    peer.check()
    assert peer.extra_lines() == []
    assert driver.stats["oks_recovered"] == 0


@pytest.mark.timeout(20)
def test_silent_printer_raises_no_answer_naming_the_last_line(run):
    config = DriverConfig(boot_timeout_s=0.3, min_timeout_s=0.3, poll_s=0.01, probe_attempts=2)
    # the probe that went unanswered is said again under its own number, never a new one
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G28"), b"ok\n"),
            (cs(2, "M105"), b""),
            (cs(3, "M118 E1 neatskin-probe 3"), b""),
            (cs(3, "M118 E1 neatskin-probe 3"), b""),
        ],
        config=config,
    )
    driver.connect()
    driver.send("G28")
    with pytest.raises(E.NoAnswer) as info:
        driver.send("M105")
    assert info.value.last_line == 1 and "N2 'M105'" in str(info.value)
    peer.check()
    assert peer.extra_lines(wait_s=0.5) == []


@pytest.mark.timeout(20)
def test_connect_to_a_silent_port_raises_no_answer():
    config = DriverConfig(boot_timeout_s=0.1, min_timeout_s=0.3, poll_s=0.01, probe_attempts=2)
    peer = ScriptedPeer([(b"N0 M110 N0*125\n", b"")] * 3)  # M110 is idempotent: said again, then given up
    driver = MarlinDriver(serial.serial_for_url(peer.path, do_not_open=True), config=config)
    try:
        with pytest.raises(E.NoAnswer) as info:
            driver.connect()
        assert info.value.last_line is None and "no line of this session was acknowledged" in str(info.value)
        peer.check()
        assert peer.extra_lines() == []
    finally:
        driver.close()
        peer.close()


@pytest.mark.timeout(20)
def test_unknown_command_is_refused_and_numbering_goes_on(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "G999"), b'echo:Unknown command: "G999"\nok\n'),
            (cs(2, "G1 X1"), b"echo:Home XYZ First\nok\n"),
            (cs(3, "M105"), b"ok\n"),
        ]
    )
    driver.connect()
    with pytest.raises(E.CommandRejected, match="Unknown command"):
        driver.send("G999")
    with pytest.raises(E.CommandRejected, match="Home XYZ First"):
        driver.send("G1 X1")
    assert driver.send("M105") == []
    peer.check()


@pytest.mark.timeout(20)
def test_host_action_and_echo_lines_are_kept(run):
    peer, driver = run(
        [
            BOOT,
            HELLO,
            (cs(1, "M118 A1 action:pause"), b"//action:pause\nok\n"),
            (cs(2, "M118 E1 NS press=3 phase=press"), b"echo:NS press=3 phase=press\nok\n"),
        ]
    )
    driver.connect()
    assert driver.send("M118 A1 action:pause") == ["//action:pause"]
    assert driver.actions == ["//action:pause"]
    assert driver.send("M118 E1 NS press=3 phase=press") == ["echo:NS press=3 phase=press"]
    peer.check()


@pytest.mark.timeout(20)
def test_refused_line_in_a_batch_stops_the_rest(run):
    peer, driver = run([BOOT, HELLO, (cs(1, "G1 X1"), b"echo:Home XYZ First\nok\n")])
    driver.connect()
    with pytest.raises(E.CommandRejected):
        driver.send_lines(["G1 X1", "G1 X2", "M400"])
    peer.check()
    assert peer.extra_lines() == []


@pytest.mark.timeout(20)
def test_advanced_ok_reports_are_read(run):
    peer, driver = run(
        [
            BOOT,
            (b"N0 M110 N0*125\n", b"ok N0 P16 B3\n"),
            (cs(1, "G28"), b"ok N0 P16 B3\nok N1 P16 B3\n"),
            (cs(2, "M400"), b"ok N2 P16 B3\n"),
        ]
    )
    driver.connect()
    driver.send("G28")  # the stale "ok N0" is not taken for N1
    driver.send("M400")
    peer.check()
    assert driver.stats["stale_oks"] == 1


@pytest.mark.timeout(20)
def test_pipelining_starts_only_after_ok_names_its_line(run):
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, max_in_flight=4, confirm_batches=True)
    peer, driver = run(
        [
            BOOT,
            (b"N0 M110 N0*125\n", b"ok N0 P16 B3\n"),
            (cs(1, "G1 X1"), b""),
            (cs(2, "G1 X2"), b""),  # three lines out before any ok
            (cs(3, "G1 X3"), b"ok N1 P15 B3\nok N2 P14 B2\nok N3 P13 B1\n"),
            # the batch ends with a probe whose echo proves every line ran
            (cs(4, "M118 E1 neatskin-probe 4"), b"echo:neatskin-probe 4\nok N4 P16 B3\n"),
        ],
        config=config,
    )
    driver.connect()
    driver.send_lines(["G1 X1", "G1 X2", "G1 X3"])
    peer.check()
    assert driver.stats["max_in_flight"] == 3


@pytest.mark.timeout(20)
def test_no_banner_times_out_cleanly_and_m119_parses(run):
    peer, driver = run(
        [HELLO, (cs(1, "M119"), b"Reporting endstop status\nx_min: open\ny_min: open\nz_min: TRIGGERED\nok\n")]
    )
    driver.connect(boot_timeout_s=0.2)
    assert driver.endstops() == {"x_min": False, "y_min": False, "z_min": True}
    peer.check()


@pytest.mark.timeout(20)
def test_dead_port_raises_port_dead(run):
    peer, driver = run([BOOT, HELLO, (cs(1, "G28"), b"ok\n")])
    driver.connect()
    driver.send("G28")
    peer.check()
    peer.pty.close()  # the USB cable is pulled: the master and our slave fd vanish
    with pytest.raises((E.PortDead, E.NoAnswer)) as info:
        driver.send("M105")
    assert info.value.last_line == 1


@pytest.mark.timeout(20)
def test_emergency_stop_goes_out_at_once_while_a_line_is_in_flight(run):
    peer, driver = run([BOOT, HELLO, (cs(1, "G4 S30"), b"")])
    driver.connect()
    import threading

    errors = []
    thread = threading.Thread(target=lambda: _capture(errors, driver.send, "G4 S30"))
    thread.start()
    peer.check()
    driver.emergency_stop()
    thread.join(timeout=5)
    assert not thread.is_alive()
    assert isinstance(errors[0], E.EmergencyStopped)
    assert peer.extra_lines() == [b"M112\n"]


@pytest.mark.timeout(20)
def test_framed_input_and_bad_gcode_are_refused_before_sending(run):
    peer, driver = run([BOOT, HELLO])
    driver.connect()
    with pytest.raises(ValueError, match="framing"):
        driver.send("N5 G28*1")
    from neatskin.errors import ConfigError

    with pytest.raises(ConfigError):
        driver.send_lines(["G28", "X10 nonsense"])
    for _ in range(2):  # the second time from the driver's parse cache: the same refusals
        with pytest.raises(ConfigError) as info:
            driver.send_lines(["G28", "X10 nonsense", "M400 ; sync", "Q2"], source="press 7 travel")
        assert [(p.file, p.field) for p in info.value.problems] == [
            ("press 7 travel", "line 2"),
            ("press 7 travel", "line 4"),
        ]
        with pytest.raises(ValueError, match="framing"):
            driver.send_lines(["G28", "N3 G1 X1*5"])
    peer.check()
    assert peer.extra_lines() == []


def _capture(errors, fn, *args):
    try:
        fn(*args)
    except Exception as exc:  # noqa: BLE001
        errors.append(exc)


def test_open_refuses_a_bad_url():
    with pytest.raises(E.PortDead, match="cannot use port"):
        MarlinDriver.open("nosuchscheme://x")
    assert os.path.exists("/dev/ptmx")

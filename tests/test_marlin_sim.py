"""The simulated printer: Marlin's exact replies, the line protocol, homing, limits, the planner and the motion clock."""

from __future__ import annotations

import math
import time

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.gcode.machine import limited_feed_and_accel, trapezoid_time_s
from neatskin.gcode.parse import checksum
from neatskin.gcode.profile import load_printer_profile
from neatskin.marlin import errors as E
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.marlin.replies import PROBE_TAG
from neatskin.sim.firmware import MarlinCore
from neatskin.sim.motion import trapezoid_distance_mm
from neatskin.sim.printer import SimulatedPrinter

# No test here loses an `ok` on purpose, so a line's deadline only bounds a hang: 3 s, not 0.5 s, so that a loaded
# machine holding the simulator's thread off the CPU for a second or two gets a late `ok`, not NoAnswer (at 0.5 s,
# the socket test's server thread held up 2.5 s ended in NoAnswer, and 0.5 s near its end put a probe in the
# commands it checks; it failed once at load 15). A real hang still ends in NoAnswer: the deadline and 3 probes.
CONFIG = DriverConfig(boot_timeout_s=0.05, min_timeout_s=3.0, poll_s=0.01, motion_time_scale=0.0)


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


def framed(n: int, command: str) -> bytes:
    body = f"N{n} {command}"
    return f"{body}*{checksum(body)}\n".encode()


def talk(core: MarlinCore, data: bytes) -> bytes:
    core.receive(data)
    core.step()
    return core.take_output()


def fresh(profile, **kw) -> MarlinCore:
    core = MarlinCore(profile, **kw)
    core.take_output()
    return core


def test_boot_banner_starts_with_start(profile):
    core = MarlinCore(profile)
    assert core.take_output().split(b"\n")[0] == b"start"


def test_line_protocol_replies_are_marlins(profile):
    core = fresh(profile)
    assert talk(core, framed(1, "M105")) == b"ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0\n"
    # Marlin sends a bare `ok` after every `Resend:` (queue.cpp flush_and_request_resend; the real firmware does)
    assert talk(core, b"N2 M105*1\n") == b"Error:checksum mismatch, Last Line: 1\nResend: 2\nok\n"
    assert talk(core, b"N2 M105\n") == b"Error:No Checksum with line number, Last Line: 1\nResend: 2\nok\n"
    assert talk(core, framed(3, "M105")) == (
        b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\nok\n"
    )
    assert talk(core, framed(1, "M105")) == b""  # Marlin 2.1 drops a repeat just below the counter
    assert talk(core, framed(2, "G21")) == b"ok\n"
    assert talk(core, b"G91\n") == b"ok\n"  # unnumbered lines need no checksum
    assert talk(core, framed(0, "M110 N0")) == b"ok\n"
    assert talk(core, framed(1, "G999 X1")) == b'echo:Unknown command: "G999 X1"\nok\n'
    assert [t for _, t in core.executed] == ["M105", "G21", "G91", "M110 N0", "G999 X1"]


def test_without_ok_after_resend_a_resend_stands_alone(profile):
    core = fresh(profile, ok_after_resend=False)  # a Repetier-like peer
    talk(core, framed(1, "M105"))
    assert talk(core, framed(3, "M105")) == b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\n"


def test_marlin_2_0_answers_a_repeat_and_1_x_adds_ok_after_resend(profile):
    core = fresh(profile, marlin_version="2.0", ok_after_resend=True)
    talk(core, framed(1, "M105"))
    assert talk(core, framed(1, "M105")) == (
        b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\nok\n"
    )


def test_homing_limits_m114_m119_m211_m118(profile):
    core = fresh(profile)
    # as stock Marlin (the native build does it: test_marlin_real_vs_sim): a move before homing runs, unclamped
    assert talk(core, b"G1 X-5 Y10\n") == b"ok\n"
    assert talk(core, b"M114\n") == b"X:-5.00 Y:10.00 Z:0.00 E:0.00 Count X:-400 Y:800 Z:0\nok\n"
    # a third of 25 s; Z (not homed) rises 5 mm first, and G28 reports the position (the native build does both)
    assert talk(core, b"G28 X\n") == (
        b"echo:busy: processing\n" * 3 + b"X:0.00 Y:10.00 Z:5.00 E:0.00 Count X:0 Y:800 Z:2000\nok\n"
    )
    assert talk(core, b"G1 X-5 Y-5\n") == b"ok\n"  # the soft limits hold on the homed axis only
    assert talk(core, b"M114\n") == b"X:0.00 Y:-5.00 Z:5.00 E:0.00 Count X:0 Y:-400 Z:2000\nok\n"
    # 25 s of homing, virtual: Z rises to 10, every axis homes, Z moves to 5
    assert talk(core, b"G28\n") == (
        b"echo:busy: processing\n" * 3 + b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"
    )
    assert talk(core, b"M119\n") == b"Reporting endstop status\nx_min: TRIGGERED\ny_min: TRIGGERED\nz_min: open\nok\n"
    assert talk(core, b"G1 X300 Y-5 Z12 F6000\n") == b"ok\n"  # outside the soft limits: clipped, as Marlin
    # Count is where the queued motion ends (Marlin's planner position), not where the probe is now
    assert talk(core, b"M114\n") == b"X:220.00 Y:0.00 Z:12.00 E:0.00 Count X:17600 Y:0 Z:4800\nok\n"
    assert core.clip_events[-1][2:] == ((300.0, -5.0, 12.0), (220.0, 0.0, 12.0))
    assert talk(core, b"M211\n") == (  # M211.cpp's report, as the native build prints it
        b"  M211 S1 ; ON\n  Min:  X0.00 Y0.00 Z0.00   Max:  X220.00 Y220.00 Z250.00\nok\n"
    )
    assert talk(core, b"M211 S0\n") == b"ok\n"  # setting says nothing
    assert talk(core, b"G1 X-5 Z-1\nM114\n").endswith(b"X:-5.00 Y:0.00 Z:-1.00 E:0.00 Count X:-400 Y:0 Z:-400\nok\n")
    assert core.timeline.end_mm[::2] == (0.0, 0.0)  # unclamped, but the probe stops at the end of its travel
    assert talk(core, b"M211 S1\nG1 X-6 Z-2\nM114\n").endswith(b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n")
    assert core.timeline.end_mm[::2] == (5.0, 1.0)  # the steps lost against the frame stay lost
    talk(core, b"G1 X220 Y0 Z12\nM400\n")
    assert talk(core, b"M118 E1 NS press=3 phase=press\n") == b"echo:NS press=3 phase=press\r\nok\n"
    assert talk(core, b"M118 A1 action:pause\n") == b"//action:pause\r\nok\n"
    # G92 reports the position it set; the steppers did not move
    assert talk(core, b"G92 X0\n") == b"X:0.00 Y:0.00 Z:12.00 E:0.00 Count X:17600 Y:0 Z:4800\nok\n"


def test_m114_before_homing_is_zeros_and_count_follows_the_queue(profile):
    core = fresh(profile)
    assert talk(core, b"M114\n") == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"
    talk(core, b"G28\n")
    core.receive(b"G1 X100 F600\nM114\n")  # 10 s of motion queued; M114 runs at once
    core.step()
    assert core.take_output() == b"ok\nX:100.00 Y:0.00 Z:5.00 E:0.00 Count X:8000 Y:0 Z:2000\nok\n"
    assert core.timeline.position_mm(core.clock.now())[0] < 100.0  # the probe is still on its way


def test_a_move_before_homing_steps_the_probe_from_where_it_is(profile):
    """The firmware believes zeros at boot; the probe is at the park position. A move before homing steps each
    axis by the same distance from where the probe is; past the end of the bed's travel the steps are lost
    (the probe stops there), so the difference between the two changes; G28 of an axis ends it for that axis."""
    core = fresh(profile)
    park = tuple(profile.park_mm)  # (0, 200, 60) mm
    talk(core, b"G1 X30 Y-50 Z-10 F6000\nM400\n")
    assert core.timeline.position_mm(core.clock.now()) == (park[0] + 30, park[1] - 50, park[2] - 10)
    assert talk(core, b"M114\n") == b"X:30.00 Y:-50.00 Z:-10.00 E:0.00 Count X:2400 Y:-4000 Z:-4000\nok\n"
    talk(core, b"G1 Y30\nM400\n")  # 80 mm up in Y from 150 mm: 10 mm past the bed's 220 mm, lost on the frame
    assert core.timeline.position_mm(core.clock.now())[1] == profile.bed_y_mm
    talk(core, b"G1 Y10\nM400\n")
    assert core.timeline.position_mm(core.clock.now())[1] == profile.bed_y_mm - 20
    talk(core, b"G28 Z\nM400\n")  # Z goes home, then to 5 mm; X and Y stay where the probe is
    assert core.timeline.position_mm(core.clock.now()) == (park[0] + 30, profile.bed_y_mm - 20, 5.0)
    talk(core, b"G28\nG1 X10 Y20 Z7\nM400\n")  # homed: the probe is where the firmware believes
    assert core.timeline.position_mm(core.clock.now()) == (10.0, 20.0, 7.0)
    assert [t for _, t in core.executed][-3:] == ["G28", "G1 X10 Y20 Z7", "M400"]


def test_a_printer_built_with_no_motion_before_homing_refuses_until_every_axis_is_homed(profile):
    """Marlin's NO_MOTION_BEFORE_HOMING (motion.cpp homing_needed_error): the move does nothing but name the axes not
    homed, then `ok`; the probe stays where it is."""
    core = fresh(profile, no_motion_before_homing=True)
    park = tuple(profile.park_mm)
    assert talk(core, b"G1 X10\n") == b"echo:Home XYZ First\nok\n"
    # G28's own Z raise is no G0/G1: it runs
    assert talk(core, b"G28 X\n") == (
        b"echo:busy: processing\n" * 3 + b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"
    )
    assert talk(core, b"G1 X10\n") == b"echo:Home YZ First\nok\n"
    assert talk(core, b"M114\n") == b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n"
    assert core.timeline.position_mm(core.clock.now()) == (0.0, park[1], park[2] + 5)  # only the homing moved it
    talk(core, b"G28\n")
    assert talk(core, b"G1 X10\nM400\n") == b"ok\nok\n"
    assert core.timeline.position_mm(core.clock.now()) == (10.0, 0.0, 5.0)


def test_m84_keeps_the_axes_homed(profile):
    """Stock Marlin (HOME_AFTER_DEACTIVATE off) keeps its homing when the steppers go off: the soft limits still
    clamp, and M119 still reports the endstops. The native build printed these very lines (G28, M84, G1 X-5, M400,
    M114, M119; Z stands 5 mm above its endstop after G28, so z_min is open until G1 Z0)."""
    core = fresh(profile)
    talk(core, b"G28\n")
    assert talk(core, b"M84\n") == b"ok\n"
    assert talk(core, b"G1 X-5\nM400\nM114\n").endswith(b"X:0.00 Y:0.00 Z:5.00 E:0.00 Count X:0 Y:0 Z:2000\nok\n")
    assert talk(core, b"M119\n") == b"Reporting endstop status\nx_min: TRIGGERED\ny_min: TRIGGERED\nz_min: open\nok\n"
    talk(core, b"G1 Z0\nM400\n")
    assert talk(core, b"M119\n") == (
        b"Reporting endstop status\nx_min: TRIGGERED\ny_min: TRIGGERED\nz_min: TRIGGERED\nok\n"
    )


def test_m112_halts_until_a_reset(profile):
    """Without an emergency parser: an unnumbered M112 kills as it is read, a numbered one as it runs;
    M112 inside a text is no command; after a kill nothing answers, M999 neither, until a reset."""
    core = fresh(profile)
    assert talk(core, b"M118 E1 M112 inside\n") == b"echo:M112 inside\r\nok\n"
    assert talk(core, framed(1, "M112")) == b"echo:M112 Shutdown\nError:Printer halted. kill() called!\n"
    assert talk(core, framed(2, "M105")) == b""
    assert talk(core, b"M999\n") == b""
    core.reset()
    assert talk(core, b"M112\n").endswith(b"echo:M112 Shutdown\nError:Printer halted. kill() called!\n")
    assert [t for _, t in core.executed] == ["M118 E1 M112 inside", "M112"]


def test_m999_asks_for_the_line_after_the_last_numbered_one(profile):
    """M999 on a running printer (M999.cpp -> queue.cpp flush_and_request_resend): `Resend: <last N + 1>` and a bare
    ok, then its own ok; with ADVANCED_OK its own ok carries P and B (and N when numbered), the resend's stays bare;
    a true S (S1, a bare S) skips the resend; the receive buffer is emptied. The real firmware's bytes:
    tests/test_marlin_real_vs_sim.py::test_m999_answers_as_the_real_firmware."""
    for advanced, own in ((False, b"ok\n"), (True, b"ok P15 B3\n")):
        core = fresh(profile, advanced_ok=advanced)
        for n in range(1, 10):
            talk(core, framed(n, "M400"))
        assert talk(core, b"M999\n") == b"Resend: 10\nok\n" + own
        assert talk(core, b"M999 S1\n") == talk(core, b"M999 S\n") == own
        assert talk(core, b"M999 S0\n") == b"Resend: 10\nok\n" + own
        numbered = b"ok N10 P15 B3\n" if advanced else b"ok\n"
        assert talk(core, framed(10, "M999")) == b"Resend: 11\nok\n" + numbered
        core.receive(b"M999\n")
        core.rx.extend(b"M118 E1 flushed\n")  # still in the receive buffer when M999 runs: emptied
        core.step()
        assert core.take_output() == b"Resend: 11\nok\n" + own
        assert talk(core, b"M105\n").startswith(b"ok T:")
    assert [t for _, t in core.executed if "flushed" in t] == []


def test_advanced_ok_reports_line_planner_and_buffer(profile):
    core = fresh(profile, advanced_ok=True)
    # B counts the command being acknowledged as still in Marlin's ring buffer
    # and the planner one slot short of its size, as Marlin's ring keeps one empty: P15 when idle
    assert talk(core, framed(1, "G28")).endswith(b"ok N1 P15 B3\n")
    assert talk(core, framed(2, "G1 X50 F6000")) == b"ok N2 P14 B3\n"


def test_motion_clock_and_probe_position_follow_the_trapezoid(profile):
    core = fresh(profile)
    talk(core, b"G28\n")
    t_home = core.clock.now()
    assert t_home == pytest.approx(profile.homing_time_s)  # the measured G28, its Z raises included
    talk(core, b"G1 X100 F6000\nM400\n")
    feed, accel = limited_feed_and_accel((100.0, 0.0, 0.0), 100.0, profile)
    duration = trapezoid_time_s(100.0, feed, accel)
    assert core.clock.now() == pytest.approx(t_home + duration)
    tl = core.timeline
    assert tl.position_mm(t_home) == (0.0, 0.0, 5.0)  # Z_POST_CLEARANCE above the endstop
    assert tl.position_mm(t_home + duration / 2)[0] == pytest.approx(50.0)  # symmetric profile: halfway at half time
    v = min(feed, math.sqrt(accel * 100.0))
    t_a = v / accel
    assert tl.position_mm(t_home + t_a)[0] == pytest.approx(v * v / (2 * accel))
    assert tl.position_mm(t_home + duration + 5) == (100.0, 0.0, 5.0)
    sim = SimulatedPrinter(profile)
    sim.core = core
    # the move the probe last rested after, and every later one
    assert [seg.p1_mm for seg in sim.segments(t_home + 1)] == [(0.0, 0.0, 5.0), (100.0, 0.0, 5.0)]
    assert [seg.p1_mm for seg in sim.segments(t_home + duration + 1)] == [(100.0, 0.0, 5.0)]


def test_full_planner_delays_the_ok_until_a_slot_frees(profile):
    core = fresh(profile)
    talk(core, b"G28\n")
    t0 = core.clock.now()
    first = len(core.timeline.segments)  # after G28's homing and Z moves
    for i in range(profile.planner_buffer_size):
        talk(core, f"G1 X{10 * (i % 2 + 1)} F6000\n".encode())
    assert core.clock.now() == t0  # 16 slots: every ok at once, no time passes
    assert core.timeline.pending(t0) == 16
    talk(core, b"G1 X30 F6000\n")
    assert core.clock.now() == pytest.approx(core.timeline.segments[first].t1_s)  # waited for the first move


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 300), st.floats(1, 300), st.floats(10, 5000), st.floats(0, 1))
def test_trapezoid_distance_inverts_the_timing(distance, feed, accel, share):
    total = trapezoid_time_s(distance, feed, accel)
    assert trapezoid_distance_mm(total, distance, feed, accel) == pytest.approx(distance, rel=1e-9, abs=1e-9)
    a, b = sorted((share * total, min(total, share * total + total / 7)))
    assert trapezoid_distance_mm(a, distance, feed, accel) <= trapezoid_distance_mm(b, distance, feed, accel) + 1e-12


@pytest.mark.timeout(20)
def test_raw_bytes_on_a_real_pty(profile):
    sim = SimulatedPrinter(profile)
    path = sim.start_pty()
    port = serial.Serial(path, 115200, timeout=0.5)
    try:
        port.reset_input_buffer()
        port.write(framed(1, "M110 N0") + b"N1 G28*99\n")
        got = b""
        end = time.monotonic() + 5
        while got.count(b"ok\n") < 2 and time.monotonic() < end:
            got += port.read(port.in_waiting or 1)
        # as in Marlin, a line is checked when it is read, ahead of running the queue (the M110 here);
        # the bare ok after `Resend:` comes before the M110's own
        assert got.split(b"M301 P22.20 I1.08 D114.00\n")[-1] == (
            b"Error:checksum mismatch, Last Line: 0\nResend: 1\nok\nok\n"
        )
    finally:
        port.close()
        sim.stop()


@pytest.mark.timeout(20)
@pytest.mark.parametrize("transport", ["pty", "in-process"])
def test_driver_against_the_sim(profile, transport):
    sim = SimulatedPrinter(profile)
    port = serial.serial_for_url(sim.start_pty(), do_not_open=True) if transport == "pty" else sim.serial()
    driver = MarlinDriver(port, config=CONFIG)
    try:
        driver.connect()
        driver.send("G1 X10")  # stock Marlin moves before homing, from where it believes it is (zeros at boot)
        assert driver.position().x_mm == 10.0
        driver.send("G28")
        driver.send_lines(["G1 X100 Y50 Z10 F6000", "G1 Z2 F300", "M400"])
        assert sim.probe_position() == (100.0, 50.0, 2.0)
        pos = driver.position()
        assert (pos.x_mm, pos.y_mm, pos.z_mm) == (100.0, 50.0, 2.0)
        assert pos.count == (8000, 4000, 800)
        assert driver.send("M118 E1 NS press=3 phase=press") == ["echo:NS press=3 phase=press"]
        sim.reset()
        with pytest.raises(E.PrinterReset):
            driver.send("M105")
        driver.reconnect(boot_timeout_s=0.05)
        # homing was lost with the reset: the firmware believes zeros again, where the probe is not; the driver
        # says so, and the campaign homes before it moves (its preamble: test_campaign_run)
        assert "G28" in E.PrinterReset.fix
        pos = driver.position()
        assert (pos.x_mm, pos.y_mm, pos.z_mm, pos.count) == (0.0, 0.0, 0.0, (0, 0, 0))
        assert sim.probe_position() == (100.0, 50.0, 2.0)
    finally:
        driver.close()
        sim.stop()


@pytest.mark.timeout(20)
def test_the_driver_raises_a_refused_move(profile):
    """A printer built with NO_MOTION_BEFORE_HOMING refuses a move before homing: the driver raises it, through a pty."""
    sim = SimulatedPrinter(profile, no_motion_before_homing=True)
    driver = MarlinDriver(serial.serial_for_url(sim.start_pty(), do_not_open=True), config=CONFIG)
    try:
        driver.connect()
        with pytest.raises(E.CommandRejected, match="Home XYZ First"):
            driver.send("G1 X10")
        driver.send("G28")
        driver.send_lines(["G1 X10", "M400"])
        assert sim.probe_position() == (10.0, 0.0, 5.0)
    finally:
        driver.close()
        sim.stop()


@pytest.mark.timeout(20)
def test_scaled_time_really_waits_and_keeps_alive(profile):
    sim = SimulatedPrinter(profile, time_mode="scaled", speed=10.0)
    driver = MarlinDriver(sim.serial(), config=DriverConfig(boot_timeout_s=0.05, min_timeout_s=1.0, poll_s=0.01))
    try:
        driver.connect()
        start = time.monotonic()
        driver.send("G4 S5")  # 5 s at 10x: half a second, with a keep-alive every 2 printer seconds
        elapsed = time.monotonic() - start
        assert 0.45 <= elapsed < 2.0
        assert driver.stats["busy"] >= 1
        assert sim.now_s() >= 5.0
    finally:
        driver.close()


@pytest.mark.timeout(60)  # a hang ends in NoAnswer within 12 s (CONFIG); this guards the server thread
def test_driver_over_socket_url(profile):
    """socket:// goes through pyserial's own read/write (no file descriptor fast path)."""
    import socket
    import threading

    sim = SimulatedPrinter(profile)
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        conn, _ = server.accept()
        conn.settimeout(0.02)
        with conn:
            while not stop.is_set():
                try:
                    data = conn.recv(4096)
                    if not data:
                        return
                except TimeoutError:
                    data = b""
                with sim.lock:
                    sim.core.receive(data)
                    sim.core.step()
                    out = sim.core.take_output()
                if out:
                    conn.sendall(out)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    driver = MarlinDriver.open(f"socket://127.0.0.1:{server.getsockname()[1]}", config=CONFIG)
    moves = [f"G1 X{i} Y{2 * i} F6000" for i in range(1, 51)]
    try:
        driver.connect()
        driver.send("G28")
        driver.send_lines([*moves, "M400"])
        assert driver.position().y_mm == 100.0
        # every command once, in order; an `ok` late past its deadline (a loaded machine) may add the driver's own
        # lost-ok probe, which is not a command of ours
        ran = [t for _, t in sim.executed if PROBE_TAG not in t]
        assert ran[ran.index("G28") :] == ["G28", *moves, "M400", "M114"]
    finally:
        driver.close()
        stop.set()
        thread.join(timeout=2)
        server.close()


def test_vectorised_positions_equal_the_timeline(protocols_dir):
    """positions_mm (the dry run's DAQ clock) gives what Timeline.position_mm gives, time by time."""
    import numpy as np

    from neatskin.gcode.profile import load_printer_profile
    from neatskin.sim.motion import Timeline, positions_mm

    timeline = Timeline(load_printer_profile(protocols_dir / "printers" / "paper.toml"), (0.0, 0.0, 0.0))
    timeline.add_homing(0.0, (0.0, 0.0, 10.0), 2.0)
    for target, feed in (
        ((100.0, 100.0, 15.5), 100.0),
        ((100.0, 100.0, 5.5), 5.0),
        ((100.0, 100.0, 2.0), 2.0),
        ((100.0, 100.0, 2.0), 2.0),
        ((130.0, 95.0, 15.5), 50.0),
    ):
        timeline.add_move(timeline.end_s + 0.25, target, feed)
    times = np.sort(np.random.default_rng(5).uniform(-1.0, timeline.end_s + 1.0, 2000))
    expected = np.array([timeline.position_mm(t) for t in times])
    np.testing.assert_allclose(positions_mm(timeline.segments, times), expected, rtol=0, atol=1e-9)

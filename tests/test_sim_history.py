"""The simulated printer's memory stays flat as a campaign grows: bounded moves, executed lines and clip events,
with the same answers as an unbounded history for every time a caller may still ask about."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from neatskin.gcode.parse import checksum
from neatskin.gcode.profile import load_printer_profile
from neatskin.sim.firmware import MarlinCore
from neatskin.sim.motion import HistoryForgotten, Timeline
from neatskin.sim.printer import SimulatedPrinter


@pytest.fixture(scope="module")
def profile(protocols_dir):
    return load_printer_profile(protocols_dir / "printers" / "paper.toml")


def framed(n: int, command: str) -> bytes:
    body = f"N{n} {command}"
    return f"{body}*{checksum(body)}\n".encode()


def press_lines(i: int) -> list[str]:
    """One paper-like press: travel, descend, press, hold, lift (5 moves, a dwell, syncs, an echo)."""
    x, y = 100 + (i * 7) % 40, 90 + (i * 13) % 30
    return [
        f"M118 E1 NS press={i} phase=travel",
        "G0 Z15.5 F300",
        f"G0 X{x} Y{y} F6000",
        "M400",
        "G1 Z5.5 F300",
        "M400",
        "G1 Z2 F120",
        "M400",
        "G4 P1200",
        "M400",
        "G0 Z15.5 F300",
        "M400",
    ]


def run_presses(core: MarlinCore, first: int, count: int, n: int) -> tuple[int, list[float]]:
    """Feed presses to the core as a host would; the printer time at the start of each press."""
    starts = []
    for i in range(first, first + count):
        starts.append(core.clock.now())
        for command in press_lines(i):
            n += 1
            core.receive(framed(n, command))
            core.step()
            core.take_output()
    return n, starts


def homed_core(profile, **kw) -> MarlinCore:
    core = MarlinCore(profile, **kw)
    core.receive(b"G28\n")
    core.step()
    core.receive(framed(0, "M110 N0"))
    core.step()
    core.take_output()
    return core


def test_a_bounded_printer_answers_recent_questions_exactly_as_an_unbounded_one(profile):
    bounded = homed_core(profile, history_lines=50, keep_segments=16)
    unbounded = homed_core(profile, history_lines=10**9, keep_segments=10**9)
    n = 0
    for block in range(20):
        n_b, starts = run_presses(bounded, block * 10, 10, n)
        n_u, starts_u = run_presses(unbounded, block * 10, 10, n)
        n = n_b
        assert n_b == n_u and starts == starts_u
        assert len(bounded.timeline.segments) <= 16 + 2
        t_last = starts[-1]  # the latest press, as the recorder asks for it
        assert bounded.timeline.segments_from(t_last) == unbounded.timeline.segments_from(t_last)
        times = np.linspace(t_last, bounded.clock.now() + 1.0, 97)
        assert [bounded.timeline.position_mm(t) for t in times] == [unbounded.timeline.position_mm(t) for t in times]
    assert bounded.executed_count == unbounded.executed_count == 2 + 200 * len(press_lines(0))
    assert list(bounded.executed) == list(unbounded.executed)[-50:]
    assert bounded.timeline.forgotten > 900
    with pytest.raises(HistoryForgotten, match="before the oldest move kept"):
        bounded.timeline.segments_from(starts[0] - 500.0)
    with pytest.raises(HistoryForgotten):
        bounded.timeline.position_mm(1.0)
    assert unbounded.timeline.position_mm(1.0) == unbounded.timeline.position_mm(1.0)  # unbounded: still known


def test_forget_before_keeps_the_move_the_probe_rests_after(profile):
    timeline = Timeline(profile, (0.0, 0.0, 0.0), keep_segments=1000)
    full = Timeline(profile, (0.0, 0.0, 0.0), keep_segments=1000)
    for tl in (timeline, full):
        tl.add_homing(0.0, (0.0, 0.0, 10.0), 2.0)
        for i in range(30):
            tl.add_move(tl.end_s + 0.25, (10.0 + i, 20.0, 5.0 + i % 3), 50.0)
    t = full.segments[12].t1_s + 0.1  # resting after move 12, before move 13 starts
    assert timeline.forget_before(t) == 12
    assert timeline.segments[0] == full.segments[12]
    assert timeline.segments_from(t) == full.segments_from(t) == full.segments[12:]
    assert timeline.position_mm(t) == full.position_mm(t)
    assert timeline.forget_before(t) == 0  # idempotent
    with pytest.raises(HistoryForgotten):
        timeline.segments_from(full.segments[5].t1_s)


def test_the_printer_says_what_it_forgot(profile):
    printer = SimulatedPrinter(profile, history_lines=10, keep_segments=4)
    core = printer.core
    core.receive(b"G28\n")
    core.step()
    for i in range(40):
        core.receive(f"G1 X{10 + i} F6000\n".encode())
        core.step()
    assert printer.executed_count == 41 and len(printer.executed) == 10
    assert printer.executed[-1] == (None, "G1 X49 F6000")
    t = core.timeline.segments[-2].t1_s
    assert printer.segments(t) == core.timeline.segments[-2:]
    assert printer.forget_before(t) >= 1
    assert printer.segments(t) == core.timeline.segments  # the resting move and the last one


@pytest.mark.slow
def test_memory_is_flat_over_a_long_run_of_moves(profile):
    """Default bounds: after the windows are full, 1,000 more presses (12,000 lines, 5,000 moves) add
    next to nothing; the unbounded history grew by megabytes over the same presses."""
    tracemalloc.start()  # from the start: every object the history holds is traced
    try:
        core = homed_core(profile)
        n, _ = run_presses(core, 0, 1200, 0)  # 14,400 lines, 6,000 moves: both windows full
        before = tracemalloc.get_traced_memory()[0]
        n, _ = run_presses(core, 1200, 1000, n)
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert core.executed_count == 2 + 2200 * 12 and len(core.executed) == 10_000
    assert len(core.timeline.segments) <= 4096 + 512
    # 1,000 presses kept in full would be ~12,000 executed tuples and 5,000 segments: several MB
    assert after - before < 600_000, f"grew by {after - before} bytes over 1,000 presses"

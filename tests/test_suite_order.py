"""The suite's start order under worksteal (tests/suite_order.py): the longest tests first, spread over the workers'
first blocks by longest processing time, every test still run once."""

from __future__ import annotations

import suite_order
from suite_order import block_sizes, long_first

LONG = {"t/a.py::long_a": 172.0, "t/b.py::long_b": 60.0, "t/c.py::long_c": 59.0, "t/d.py::long_d": 56.0}
LONG["t/e.py::long_e"] = 48.0


def test_blocks_are_worksteals_first_split():
    assert block_sizes(7, 2) == [3, 4] and block_sizes(1663, 2) == [831, 832] and block_sizes(10, 3) == [3, 3, 4]
    assert sum(block_sizes(1663, 3)) == 1663


def test_each_worker_starts_with_its_share_of_the_long_tests_and_every_test_runs_once(monkeypatch):
    monkeypatch.setattr(suite_order, "LONG_S", LONG)
    ids = [f"t/short.py::test_{i}" for i in range(20)]
    ids[3:3], ids[17:17] = list(LONG)[:3], list(LONG)[3:]  # collected in the middle and at the end
    ordered = long_first(ids, ids, 2)
    assert sorted(ordered) == sorted(ids)
    first, second = ordered[:12], ordered[12:]  # 25 tests: blocks of 12 and 13
    # 172 s to the first, 60 + 59 + 56 s to the second (175 s), then 48 s to the first (172 s < 175 s)
    assert first[:3] == ["t/a.py::long_a", "t/e.py::long_e", "t/short.py::test_0"]
    assert second[:4] == ["t/b.py::long_b", "t/c.py::long_c", "t/d.py::long_d", "t/short.py::test_10"]
    assert [name for name in ordered if name not in LONG] == [name for name in ids if name not in LONG]


def test_one_worker_or_no_long_test_keeps_the_collection_order(monkeypatch):
    monkeypatch.setattr(suite_order, "LONG_S", LONG)
    ids = [f"t{i}" for i in range(9)]
    assert long_first(ids, ids, 2) == ids
    assert long_first([*ids, *LONG], [*ids, *LONG], 1) == [*ids, *LONG]


def test_the_table_names_tests_that_exist():
    """A renamed test would only lose its early start; this says which one."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    for name in suite_order.LONG_S:
        path, test = name.split("::")
        assert re.search(rf"^def {re.escape(test.split('[')[0])}\(", (root / path).read_text(), re.M), name


def test_the_real_firmware_tests_start_first_on_every_worker(monkeypatch):
    """They spin the firmware's threads: run together, they take the spare CPU from each other, not from the
    long CPU-bound tests (suite_order.REAL_TIME_FILES)."""
    timed = {"tests/test_marlin_real_vs_sim.py::test_a": 60.0, "tests/test_hil.py::test_real_firmware_b": 50.0}
    monkeypatch.setattr(suite_order, "LONG_S", {**LONG, **timed})
    ids = [*LONG, *timed, *(f"t/short.py::test_{i}" for i in range(20))]
    ordered = long_first(ids, ids, 2)
    assert sorted(ordered) == sorted(ids)
    first, second = ordered[:13], ordered[13:]
    assert (
        first[0] == "tests/test_marlin_real_vs_sim.py::test_a"
        and second[0] == "tests/test_hil.py::test_real_firmware_b"
    )
    # then the longest CPU-bound test, on the worker with less so far (50 s), the next ones on the other (60 s)
    assert second[1] == "t/a.py::long_a" and first[1:3] == ["t/b.py::long_b", "t/c.py::long_c"]


def test_the_homing_replays_go_together_to_one_worker_as_one_long_test(monkeypatch):
    """TOGETHER's tests (the first starts the firmware's side of all of them): contiguous in one block, weighed as
    the longest of them; a block too small for them leaves them in collection order; every test still once."""
    group = {name: 60.0 - 10 * k for k, name in enumerate(suite_order.TOGETHER)}
    hil = {"tests/test_hil.py::test_real_firmware_b": 50.0}
    monkeypatch.setattr(suite_order, "LONG_S", {**LONG, **group, **hil})
    ids = [*(f"t/short.py::test_{i}" for i in range(20)), *suite_order.TOGETHER, *hil, *LONG]
    ordered = long_first(ids, ids, 2)
    assert sorted(ordered) == sorted(ids)
    first, second = ordered[:14], ordered[14:]
    assert first[:3] == list(suite_order.TOGETHER) and second[0] == "tests/test_hil.py::test_real_firmware_b"
    # 60 s for the three (their longest) against hil's 50 s: the 172 s CPU-bound test goes beside hil
    assert second[1] == "t/a.py::long_a"
    few = [*suite_order.TOGETHER, "t/short.py::test_0"]
    assert long_first(few, few, 2) == few  # blocks of 2: the three fit in neither


def test_together_names_the_replays_that_start_together():
    from test_marlin_real_vs_sim import TOGETHER

    assert tuple(TOGETHER) == suite_order.TOGETHER


def test_no_hypothesis_example_has_a_deadline():
    """conftest's profile: a deadline is a timed assertion, which a loaded machine fails (as Flaky). Three tests had
    Hypothesis' default 200 ms, test_marlin_real_settings' property of marlin_float among them."""
    from hypothesis import settings
    from test_gcode_parse import test_framed_moves_round_trip
    from test_marlin_real_settings import test_marlin_float_is_the_32_bit_value_rounded_half_up
    from test_sim_housekeeping import test_duration_text_reads_back_to_the_seconds

    assert settings.default.deadline is None
    for test in (
        test_framed_moves_round_trip,
        test_marlin_float_is_the_32_bit_value_rounded_half_up,
        test_duration_text_reads_back_to_the_seconds,
    ):
        assert test._hypothesis_internal_use_settings.deadline is None, test.__name__


def test_early_work_runs_in_a_process_of_its_own_and_is_taken_once(monkeypatch):
    """tests/early.py: the started work's result comes from another process; taken once, then computed here."""
    import os

    import early

    monkeypatch.setitem(early.WORK, "t/x.py::test_x", ("os", "getpid"))
    try:
        early.start("t/x.py::test_x")
        assert early.result("t/x.py::test_x", os.getpid) != os.getpid()
        assert early.result("t/x.py::test_x", os.getpid) == os.getpid()
        assert early.result("t/y.py::test_never_started", lambda: "here") == "here"
    finally:
        early.stop()

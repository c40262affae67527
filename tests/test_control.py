"""Pause, continue and stop at safe points: the checkpoint alone (fake lift/park/clock), then real dry-run campaigns."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from neatskin.cli import main
from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses
from neatskin.errors import DataError
from neatskin.rig.control import Checkpoint, fsr_miss_cause, read_request, read_requests, read_state, request_control
from neatskin.tomlfile import resolve_path

SMOKE = resolve_path("protocols/smoke.toml")


class FakeRig:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.calls: list[str] = []
        self.t = 0.0

    def sleep(self, dt: float) -> None:
        self.t += dt
        if self.t >= 1.0 and not self.calls.count("continue-sent"):
            self.calls.append("continue-sent")
            request_control(self.folder, "continue", by="test")

    def checkpoint(self, **kw) -> Checkpoint:
        return Checkpoint(
            self.folder,
            lift=lambda: self.calls.append("lift"),
            park=lambda: self.calls.append("park"),
            sleep=self.sleep,
            clock=lambda: self.t,
            **kw,
        )


@pytest.fixture
def campaign_dir(tmp_path: Path) -> Path:
    (tmp_path / "manifest.json").write_text("{}")
    return tmp_path


def test_request_file_is_json_with_action_and_id(campaign_dir):
    req = request_control(campaign_dir, "pause", by="cli")
    data = json.loads((campaign_dir / "control.json").read_text())
    assert data["action"] == "pause" and data["id"] == req.request_id and data["by"] == "cli"
    assert read_request(campaign_dir) == req


def test_request_refuses_unknown_action_and_non_campaign(tmp_path, campaign_dir):
    with pytest.raises(DataError, match="unknown control action 'halt'"):
        request_control(campaign_dir, "halt")
    with pytest.raises(DataError, match="no manifest.json"):
        request_control(tmp_path / "nowhere", "pause")


def test_no_request_goes_on_without_lifting(campaign_dir):
    rig = FakeRig(campaign_dir)
    cp = rig.checkpoint()
    assert cp.after_press(0, []) is True
    assert rig.calls == [] and read_state(campaign_dir)["state"] == "running"


def test_stale_request_from_an_earlier_run_is_ignored(campaign_dir):
    request_control(campaign_dir, "stop")
    rig = FakeRig(campaign_dir)
    assert rig.checkpoint().after_press(0, []) is True
    assert rig.calls == []


def test_request_written_after_the_run_started_but_before_the_first_press_counts(campaign_dir):
    from neatskin.datasets.manifest import utc_now_iso

    (campaign_dir / "manifest.json").write_text(json.dumps({"started_at": utc_now_iso()}))
    request_control(campaign_dir, "stop")
    rig = FakeRig(campaign_dir)
    assert rig.checkpoint().after_press(0, []) is False and rig.calls == ["park"]
    (campaign_dir / "manifest.json").write_text(json.dumps({"started_at": "2020", "resumed_at": utc_now_iso()}))
    rig = FakeRig(campaign_dir)  # the same stop, now older than the resume: not acted on again
    assert rig.checkpoint().after_press(0, []) is True and rig.calls == []


def test_pause_lifts_waits_and_continue_goes_on(campaign_dir):
    rig = FakeRig(campaign_dir)
    cp = rig.checkpoint(poll_s=0.25)
    request_control(campaign_dir, "pause", by="test")
    assert cp.after_press(4, []) is True
    assert rig.calls == ["lift", "continue-sent"]
    assert rig.t == pytest.approx(1.0)  # four polls of 0.25 s before the continue arrived
    assert read_state(campaign_dir)["state"] == "running" and cp.pauses == 1


def test_stop_parks_and_returns_false(campaign_dir):
    rig = FakeRig(campaign_dir)
    cp = rig.checkpoint()
    request_control(campaign_dir, "stop", by="test")
    assert cp.after_press(2, []) is False
    assert rig.calls == ["park"]
    assert read_state(campaign_dir)["state"] == "stopped"


def test_auto_pause_after_n_fsr_misses_in_a_row_names_the_cause(campaign_dir):
    rig = FakeRig(campaign_dir)
    cp = rig.checkpoint(fsr_miss_limit=2)
    assert cp.after_press(0, ["fsr_missed"]) is True
    assert cp.after_press(1, ["fsr_retry:1"]) is True  # seen on a retry: the run of misses restarts
    assert cp.after_press(2, ["fsr_missed"]) is True
    assert rig.calls == []
    assert cp.after_press(3, ["fsr_retry:1", "fsr_retry:2", "fsr_missed"]) is True  # paused, then continued
    assert rig.calls == ["lift", "continue-sent"]
    reason = fsr_miss_cause(2, [2, 3])
    assert (
        "press 2, 3" in reason and "surface is likely lower than calibrated" in reason and "FSR is unplugged" in reason
    )


@pytest.mark.parametrize(
    ("continue_after_s", "timeout_s", "rehomed"),
    [(130.0, 120.0, True), (60.0, 120.0, False), (130.0, 0.0, False), (120.0, 120.0, True)],
)
def test_a_pause_longer_than_the_stepper_timeout_homes_again_before_going_on(
    campaign_dir, continue_after_s, timeout_s, rehomed
):
    rig = FakeRig(campaign_dir)
    rig.calls.append("continue-sent")  # the test sends the continue itself, at continue_after_s

    def sleep(dt: float) -> None:
        rig.t += dt
        if rig.t == continue_after_s:
            request_control(campaign_dir, "continue", by="test")

    cp = Checkpoint(
        campaign_dir,
        lift=lambda: rig.calls.append("lift"),
        park=lambda: rig.calls.append("park"),
        rehome=lambda: rig.calls.append("rehome"),
        stepper_timeout_s=timeout_s,
        sleep=sleep,
        clock=lambda: rig.t,
        poll_s=10.0,
    )
    request_control(campaign_dir, "pause", by="test")
    assert cp.after_press(0, []) is True
    assert rig.calls == ["continue-sent", "lift", *(["rehome"] if rehomed else [])]
    assert rig.t == pytest.approx(continue_after_s)


def test_a_pause_has_a_deadline(campaign_dir):
    rig = FakeRig(campaign_dir)
    rig.calls.append("continue-sent")  # no continue will come
    cp = rig.checkpoint(poll_s=10.0, max_pause_s=100.0)
    request_control(campaign_dir, "pause")
    assert cp.after_press(0, []) is False
    assert rig.calls == ["continue-sent", "lift", "park"] and rig.t == pytest.approx(100.0)
    assert "paused longer than 100 s" in str(read_state(campaign_dir)["reason"])


# ---- real dry-run campaigns -------------------------------------------------------------------------------------


def _run_in_thread(folder: Path, resume: bool = False, stepper_timeout_s: float | None = None):
    import dataclasses

    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import resume_campaign, run_campaign

    result: dict = {}

    def target() -> None:
        try:
            if resume:
                result["r"] = resume_campaign(folder, progress=False, report=False)
            else:
                protocol = load_protocol(SMOKE)
                if stepper_timeout_s is not None:
                    printer = dataclasses.replace(protocol.printer, stepper_timeout_s=stepper_timeout_s)
                    protocol = dataclasses.replace(protocol, printer=printer)
                result["r"] = run_campaign(protocol, folder, progress=False, report=False)
        except BaseException as exc:  # surfaced by the test
            result["error"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread, result


def _wait_for(predicate, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition never came true")
        time.sleep(0.02)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path_factory.mktemp("ref") / "run"
    run_campaign(load_protocol(SMOKE), folder, progress=False, report=False)
    return read_presses(folder)


def _same_rows(a, b) -> None:
    cols = ["press_id", "x_mm", "y_mm"] + [c for c in a.columns if c.startswith("dR_ohm_")]
    assert len(a) == len(b) == 12
    np.testing.assert_array_equal(a[cols].to_numpy(), b[cols].to_numpy())


def test_pause_then_continue_gives_the_rows_of_an_uninterrupted_run(tmp_path, reference):
    folder = tmp_path / "run"
    thread, result = _run_in_thread(folder)
    _wait_for(lambda: len(press_parts(folder)) >= 2)
    request_control(folder, "pause", by="test")
    _wait_for(lambda: read_state(folder).get("state") == "paused")
    held = len(press_parts(folder))
    assert 2 <= held < 12
    assert thread.is_alive()
    main(["campaign", "continue", str(folder)])
    thread.join(120)
    assert "error" not in result and result["r"].completed == 12 and not result["r"].interrupted
    assert read_state(folder)["pauses"] == 1
    _same_rows(read_presses(folder), reference)


def test_a_pause_past_the_stepper_timeout_homes_again_and_changes_no_row(tmp_path, reference):
    from neatskin.marlin.wirelog import read_wire_log

    folder = tmp_path / "run"
    thread, result = _run_in_thread(folder, stepper_timeout_s=0.05)  # Marlin's 120 s, shortened
    _wait_for(lambda: len(press_parts(folder)) >= 2)
    request_control(folder, "pause", by="test")
    _wait_for(lambda: read_state(folder).get("state") == "paused")
    time.sleep(0.3)
    main(["campaign", "continue", str(folder)])
    thread.join(120)
    assert "error" not in result and result["r"].completed == 12
    sent = b"".join(data for kind, data in read_wire_log(folder / "wire.log") if kind == ">")
    homes = [line for line in sent.split(b"\n") if b" G28 R15.5*" in line]  # the preamble's: Z raised before homing
    assert len(homes) == 2  # the program's start, and once after the pause
    # the second G28 comes after the pause's lift, and the probe is back at the safe height before the next press
    after = sent[sent.index(homes[1]) :].split(b"\n")
    assert any(b"M118 E1 NS press=" in line for line in after)
    _same_rows(read_presses(folder), reference)


def test_stop_parks_and_resume_finishes_with_the_same_rows(tmp_path, reference, monkeypatch):
    folder = tmp_path / "run"
    # the dry run's 12 presses take under a second of wall time (virtual clock): a stop sent once 3 parts were on
    # disk could arrive after the last press under load (seen in a loaded fast lane). The runner's checkpoint after
    # its 3rd press waits (at most 60 s) for the request instead, so the stop lands mid-campaign every time
    third_done, real_after_press = threading.Event(), Checkpoint.after_press

    def after_press(self, press_id, flags):
        if not third_done.is_set() and press_id >= 2:
            third_done.set()
            deadline = time.monotonic() + 60
            while not read_requests(self.folder) and time.monotonic() < deadline:
                time.sleep(0.01)
        return real_after_press(self, press_id, flags)

    monkeypatch.setattr(Checkpoint, "after_press", after_press)
    thread, result = _run_in_thread(folder)
    assert third_done.wait(120), "the campaign reached its third press"
    assert main(["campaign", "stop", str(folder)]) == 0
    thread.join(120)
    r = result["r"]
    assert r.interrupted and 3 <= r.completed < 12
    assert json.loads((folder / "manifest.json").read_text())["status"] == "interrupted"
    assert read_state(folder)["state"] == "stopped"
    monkeypatch.setattr(Checkpoint, "after_press", real_after_press)
    thread, result = _run_in_thread(folder, resume=True)  # the old stop request is not acted on again
    thread.join(120)
    assert result["r"].completed == 12 and not result["r"].interrupted
    _same_rows(read_presses(folder), reference)


def test_cli_request_on_a_campaign_that_is_not_running_says_how_to_finish_it(campaign_dir, capsys):
    (campaign_dir / "manifest.json").write_text(json.dumps({"status": "interrupted"}))
    assert main(["campaign", "continue", str(campaign_dir)]) == 0
    out = capsys.readouterr().out
    assert f"continue requested for {campaign_dir} (campaign interrupted, runner unknown)" in out
    assert f"the campaign is not running; to finish it: neatskin campaign resume {campaign_dir}" in out
    assert read_request(campaign_dir).action == "continue"


def test_requests_in_quick_succession_are_all_seen_in_order(campaign_dir):
    rig = FakeRig(campaign_dir)
    rig.calls.append("continue-sent")  # the fake sends no continue of its own
    cp = rig.checkpoint(max_pause_s=1.0, poll_s=0.5)
    request_control(campaign_dir, "pause")
    request_control(campaign_dir, "continue")
    assert cp.after_press(0, []) is True and rig.calls == ["continue-sent"]  # cancelled out: no lift
    request_control(campaign_dir, "pause")
    request_control(campaign_dir, "stop")
    assert cp.after_press(1, []) is False and rig.calls == ["continue-sent", "park"]
    assert [r.action for r in read_requests(campaign_dir)] == ["pause", "continue", "pause", "stop"]


def test_control_file_keeps_the_last_16_requests(campaign_dir):
    for k in range(20):
        request_control(campaign_dir, ("pause", "continue")[k % 2])
    requests = read_requests(campaign_dir)
    assert len(requests) == 16 and requests[-1] == read_request(campaign_dir) and requests[-1].action == "continue"

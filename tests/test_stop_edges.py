"""Stop signals at a campaign's edges, in process (the signal sent from inside a press, so it lands at a known
press): one during the last press leaves a complete campaign, not a stopped one that `resume` then refuses; a
second one stops at once, says the probe was not lifted and how to finish, and the control state says stopped."""

import json
import os
import signal

import pandas as pd
import pytest
from test_campaign_scenes import FEATURES, make_protocol

from neatskin.rig import pressing
from neatskin.rig.control import read_state
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign


def _signal_in_press(monkeypatch, at_call: int, times: int) -> None:
    """Send SIGINT to this process `times` times at the end of the at_call-th press (1-based)."""
    real = pressing._run_press
    calls = []

    def run_press(*args):
        pressed = real(*args)
        calls.append(1)
        if len(calls) == at_call:
            for _ in range(times):
                os.kill(os.getpid(), signal.SIGINT)
        return pressed

    monkeypatch.setattr(pressing, "_run_press", run_press)


@pytest.mark.timeout(120)
def test_a_stop_signal_during_the_last_press_leaves_the_campaign_complete(tmp_path, monkeypatch, caplog):
    protocol = load_protocol(make_protocol(tmp_path, *FEATURES))
    n = build_plan(protocol).n_presses
    _signal_in_press(monkeypatch, at_call=n, times=1)
    result = run_campaign(protocol, tmp_path / "run", progress=False, report=False)
    assert (result.completed, result.interrupted) == (n, False)
    assert json.loads((tmp_path / "run" / "manifest.json").read_text())["status"] == "complete"
    assert read_state(tmp_path / "run")["state"] == "finished"
    assert "SIGINT during the last press: the campaign is complete" in caplog.text
    assert "finish with: neatskin campaign resume" not in caplog.text
    assert len(pd.read_parquet(tmp_path / "run" / "presses.parquet")) == n


@pytest.mark.timeout(120)
def test_a_second_stop_signal_stops_at_once_says_so_and_resume_finishes(tmp_path, monkeypatch):
    protocol = load_protocol(make_protocol(tmp_path, *FEATURES))
    n = build_plan(protocol).n_presses
    _signal_in_press(monkeypatch, at_call=3, times=2)
    folder = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt) as stopped:
        run_campaign(protocol, folder, progress=False, report=False)
    assert str(stopped.value) == (
        "stopped at once by a second SIGINT; the probe was not lifted: check the rig, then finish with: "
        f"neatskin campaign resume {folder}"
    )
    assert read_state(folder)["state"] == "stopped"  # not "running": a monitor page shows the truth
    monkeypatch.undo()
    result = resume_campaign(folder, progress=False, report=False)
    rows = pd.read_parquet(folder / "presses.parquet")
    assert result.completed == n and len(rows) == n and rows.press_id.is_unique


@pytest.mark.timeout(120)
@pytest.mark.parametrize("resuming", [False, True])
def test_a_stop_before_the_press_loop_leaves_no_crashed_folder(tmp_path, monkeypatch, resuming):
    """Ctrl-C after the rig opened but before the press loop had its writer (the folder's inputs copied, the manifest
    saying running): a new campaign's folder, which holds no press, goes (it read "crashed": running, no process);
    a resumed one stays, with its presses, to resume again."""
    from neatskin.rig import runner

    protocol = load_protocol(make_protocol(tmp_path, *FEATURES))
    folder = tmp_path / "run"
    if resuming:
        run_campaign(protocol, folder, limit=3, report=False, progress=False)
    before = sorted(p.name for p in (folder / "presses").iterdir()) if resuming else []

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "CampaignWriter", interrupted)
    with pytest.raises(KeyboardInterrupt):
        if resuming:
            resume_campaign(folder, report=False, progress=False)
        else:
            run_campaign(protocol, folder, report=False, progress=False)
    assert folder.exists() == resuming
    if resuming:
        assert sorted(p.name for p in (folder / "presses").iterdir()) == before and len(before) == 3
        manifest = json.loads((folder / "manifest.json").read_text())
        assert (manifest["status"], manifest["stopped_by"]) == ("interrupted", "KeyboardInterrupt")

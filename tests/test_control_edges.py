"""Control requests at the edges of a run (a pause sent as the run starts, one sent to a finished campaign) and
two runs started into one folder at once."""

import json
import threading
import time

import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.datasets.manifest import create_manifest
from neatskin.errors import ConfigError, DataError, ExitCode
from neatskin.rig.control import Checkpoint, read_requests, request_control
from neatskin.rig.folder import create_campaign_folder
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan


def test_a_request_sent_before_the_manifest_exists_is_kept_and_acted_on(tmp_path):
    folder = tmp_path / "run"
    result: list = []
    sender = threading.Thread(target=lambda: result.append(request_control(folder, "stop", by="test", wait_s=20)))
    sender.start()
    time.sleep(0.5)  # the operator was quicker than the run: no folder yet
    assert sender.is_alive() and not folder.exists()
    create_manifest(folder, fsync=False, campaign="c", status="running")
    sender.join(20)
    assert not sender.is_alive() and [r.action for r in read_requests(folder)] == ["stop"]
    lifted: list[str] = []
    checkpoint = Checkpoint(folder, lift=lambda: lifted.append("lift"), park=lambda: lifted.append("park"))
    assert checkpoint.after_press(0, []) is False  # the stop is this run's: acted on at the first safe point
    assert lifted == ["park"]  # a stop parks (the lift is in the postamble it sends)


def test_a_request_to_a_folder_no_run_ever_makes_is_refused_and_writes_nothing(tmp_path, capsys):
    folder = tmp_path / "never"
    with pytest.raises(DataError) as info:
        request_control(folder, "pause", wait_s=0.3)
    assert "no manifest.json after waiting 0.3 s" in str(info.value) and "was not recorded" in str(info.value)
    assert info.value.field == "manifest.json" and not folder.exists()


@pytest.mark.parametrize("action", ["pause", "stop", "continue"])
def test_a_request_to_a_finished_campaign_is_refused_as_already_complete(tmp_path, capsys, action):
    create_manifest(tmp_path, fsync=False, campaign="c", status="complete")
    assert main(["campaign", action, str(tmp_path)]) == ExitCode.DATA  # a DataError: the exit-code table's 5
    err = capsys.readouterr().err
    assert "already complete: there is nothing to " + action in err and "[status]" in err
    assert not (tmp_path / "control.json").exists()


def test_two_runs_into_one_folder_at_once_name_the_run_that_holds_it(tmp_path):
    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    plan = build_plan(protocol)
    folder = tmp_path / "run"
    first = create_campaign_folder(protocol, plan, folder, "dry-run")  # the first run renamed its folder in
    try:
        with pytest.raises(ConfigError) as info:  # the second had checked the folder a moment before
            create_campaign_folder(protocol, plan, folder, "dry-run")
        text = str(info.value)
        assert "another run holds this folder (PID" in text and "Directory not empty" not in text
        assert info.value.field == "--out"
        assert json.loads((folder / "manifest.json").read_text())["campaign"] == protocol.name
        assert not list(tmp_path.glob(".run.staging-*"))  # the loser cleaned up its staging folder
    finally:
        first.release()


@pytest.mark.parametrize("action", ["pause", "stop", "continue"])
def test_a_manifest_that_is_a_folder_is_refused_at_once_not_waited_for(tmp_path, capsys, action):
    """Before: `campaign stop` waited its 10 s for a manifest.json that was there all along (a folder), then said
    "no manifest.json". Now: one error naming it, no wait (the wait's sleep is never called), nothing written."""
    (tmp_path / "manifest.json").mkdir()
    slept: list[float] = []
    with pytest.raises(DataError) as info:
        request_control(tmp_path, action, wait_s=10, sleep=slept.append)
    assert slept == [] and str(info.value).startswith(f"{tmp_path / 'manifest.json'}: manifest.json is a folder")
    assert main(["campaign", action, str(tmp_path)]) == ExitCode.DATA  # the CLI's request: the same refusal
    err = capsys.readouterr().err
    assert err.startswith("neatskin: error: ") and "manifest.json is a folder, not a campaign's manifest" in err
    assert not (tmp_path / "control.json").exists()

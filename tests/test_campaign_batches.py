"""The dry run's batched writer inside a campaign: every press is on disk when the loop ends (--limit), before a
pause or a stop, and after an error; a SIGKILL mid-batch loses only that batch, which resume presses again
into rows identical to an uninterrupted run."""

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS

import neatskin.datasets.writer as writer_module
import neatskin.rig.pressing as pressing
from neatskin.datasets.curate import describe
from neatskin.datasets.durable import write_error
from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses
from neatskin.errors import DataError
from neatskin.monitor.state import CampaignView
from neatskin.rig.control import Checkpoint, read_state, request_control
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign

WALL_CLOCK = ["started_at", "finished_at"]
BATCH = 16


@pytest.fixture(scope="module")
def features_protocol(tmp_path_factory):
    """The smoke protocol with 120 presses, features only (as tests/test_campaign_kill.py uses it)."""
    root = tmp_path_factory.mktemp("protocols")
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("repeats = 2", "repeats = 20").replace("waveforms = true", "waveforms = false")
    text = text.replace('signal = "waveforms"', 'signal = "features"')
    path = root / "batches.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def reference(features_protocol, tmp_path_factory):
    folder = tmp_path_factory.mktemp("reference") / "run"
    run_campaign(load_protocol(features_protocol), folder, dry_run=True, progress=False, report=False)
    return _rows(folder)


def _frozen_clock(init):
    """CampaignWriter.__init__ with the batch clock injected and frozen: the writer also closes a batch after
    DRY_RUN_BATCH_S (1 s) of wall clock, which on a loaded machine comes before BATCH presses and splits the parts
    these tests pin. Frozen, only the press count closes a part (the 1 s rule has its own clock-driven test in
    tests/test_writer_batches.py)."""

    def frozen(self, *args, **kwargs):
        init(self, *args, **kwargs, clock=lambda: 0.0)  # a TypeError if the campaign ever passes its own clock

    return frozen


@pytest.fixture
def batches(monkeypatch):
    """Dry runs of any size write parts of exactly BATCH presses (the size rule gives 120 presses one part each),
    however slow the machine."""
    monkeypatch.setattr(writer_module, "dry_run_batch_presses", lambda planned: BATCH)
    monkeypatch.setattr(writer_module.CampaignWriter, "__init__", _frozen_clock(writer_module.CampaignWriter.__init__))


def _rows(folder: Path) -> pd.DataFrame:
    df = read_presses(folder).drop(columns=WALL_CLOCK)
    df.attrs = {}
    return df


def _part_ids(folder: Path) -> dict[int, list[int]]:
    return {k: pq.read_table(p).column("press_id").to_pylist() for k, p in press_parts(folder).items()}


def _resume_equals_reference(folder: Path, reference: pd.DataFrame, durable: int) -> None:
    result = resume_campaign(folder, progress=False, report=False)
    assert (result.completed, result.written_now) == (len(reference), len(reference) - durable)
    pd.testing.assert_frame_equal(_rows(folder), reference, check_exact=True)


def test_a_limit_leaves_every_press_on_disk(features_protocol, reference, tmp_path, batches):
    folder = tmp_path / "run"
    result = run_campaign(load_protocol(features_protocol), folder, progress=False, report=False, limit=37)
    assert result.completed == result.written_now == 37 and result.interrupted is False
    assert _part_ids(folder) == {0: list(range(16)), 16: list(range(16, 32)), 32: list(range(32, 37))}
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == 37
    assert sorted(manifest["parts_sha256"], key=int) == ["0", "16", "32"]
    pd.testing.assert_frame_equal(_rows(folder), reference.iloc[:37], check_exact=True)
    _resume_equals_reference(folder, reference, 37)


def test_an_error_in_the_loop_still_writes_the_batch(features_protocol, reference, tmp_path, batches, monkeypatch):
    run_press = pressing._run_press

    def fail_at_20(protocol, plan, rig, block, pair_labels):
        if block.press_id == 20:
            raise RuntimeError("the printer caught fire")
        return run_press(protocol, plan, rig, block, pair_labels)

    monkeypatch.setattr(pressing, "_run_press", fail_at_20)
    folder = tmp_path / "run"
    with pytest.raises(RuntimeError, match="caught fire"):
        run_campaign(load_protocol(features_protocol), folder, progress=False, report=False)
    assert _part_ids(folder) == {0: list(range(16)), 16: [16, 17, 18, 19]}
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == 20
    assert manifest["stopped_by"] == "the printer caught fire"
    monkeypatch.setattr(pressing, "_run_press", run_press)
    _resume_equals_reference(folder, reference, 20)


def test_a_failed_flush_names_the_file_and_loses_only_its_batch(
    features_protocol, reference, tmp_path, batches, monkeypatch
):
    write_bytes = writer_module.write_bytes_durably

    def disk_full_at_16(path, data, **kwargs):
        if path.name == "part-000016.parquet":
            raise write_error(OSError(28, os.strerror(28)), path)
        return write_bytes(path, data, **kwargs)

    monkeypatch.setattr(writer_module, "write_bytes_durably", disk_full_at_16)
    folder = tmp_path / "run"
    with pytest.raises(DataError) as err:
        run_campaign(load_protocol(features_protocol), folder, progress=False, report=False)
    assert err.value.file.endswith("part-000016.parquet") and "disk is full" in str(err.value)
    assert _part_ids(folder) == {0: list(range(16))}  # presses 16..31 are lost with their batch
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["counts"]["completed"] == 16
    monkeypatch.setattr(writer_module, "write_bytes_durably", write_bytes)
    _resume_equals_reference(folder, reference, 16)


def test_a_pause_shows_every_press_pressed(features_protocol, reference, tmp_path, batches, monkeypatch):
    pressed: list[int] = []
    write_press = writer_module.CampaignWriter.write_press
    folder = tmp_path / "run"

    def counted(self, row, waveforms=None):
        path = write_press(self, row, waveforms)
        pressed.append(int(row["press_id"]))
        if len(pressed) == 3:  # the operator pauses once press 2 is written: the checkpoint after it pauses
            request_control(folder, "pause", by="test")
        return path

    monkeypatch.setattr(writer_module.CampaignWriter, "write_press", counted)
    result: dict = {}

    def target() -> None:
        try:
            result["r"] = run_campaign(load_protocol(features_protocol), folder, progress=False, report=False)
        except BaseException as exc:  # surfaced below
            result["error"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    deadline = time.monotonic() + 120  # a cap on waiting for the pause, not a window the test depends on
    while read_state(folder).get("state") != "paused" and time.monotonic() < deadline and thread.is_alive():
        time.sleep(0.005)
    assert read_state(folder).get("state") == "paused", result
    on_disk = read_presses(folder)["press_id"].tolist()
    assert on_disk == pressed == [0, 1, 2]
    assert describe(folder)["presses"] == len(pressed)  # what `neatskin dataset info` shows
    assert CampaignView(folder).snapshot()["counts"]["done"] == len(pressed)  # what the monitor shows
    request_control(folder, "continue", by="test")
    thread.join(120)
    assert "error" not in result and result["r"].completed == 120
    pd.testing.assert_frame_equal(_rows(folder), reference, check_exact=True)


def test_the_checkpoint_flushes_before_it_pauses_or_stops(tmp_path):
    (tmp_path / "manifest.json").write_text(json.dumps({"started_at": "2000-01-01T00:00:00+00:00"}))
    calls: list[str] = []

    def sleep(_s: float) -> None:
        calls.append("sleep")
        request_control(tmp_path, "continue", by="test")

    checkpoint = Checkpoint(
        tmp_path,
        lift=lambda: calls.append("lift"),
        park=lambda: calls.append("park"),
        flush=lambda: calls.append("flush"),
        sleep=sleep,
    )
    assert checkpoint.after_press(0, []) is True and calls == []
    request_control(tmp_path, "pause", by="test")
    assert checkpoint.after_press(1, []) is True
    assert calls == ["flush", "lift", "sleep"]
    request_control(tmp_path, "stop", by="test")
    assert checkpoint.after_press(2, []) is False
    assert calls[3:] == ["flush", "park"]


_CHILD = r"""
import sys, time
import neatskin.datasets.writer as writer
from neatskin.cli import main

writer.dry_run_batch_presses = lambda planned: int(sys.argv[1])
init = writer.CampaignWriter.__init__

def frozen_clock(self, *args, **kwargs):  # as the `batches` fixture: only the press count closes a part
    init(self, *args, **kwargs, clock=lambda: 0.0)

writer.CampaignWriter.__init__ = frozen_clock
write_press, block_after = writer.CampaignWriter.write_press, int(sys.argv[2])

def write_then_block(self, row, waveforms=None):
    path = write_press(self, row, waveforms)
    if int(row["press_id"]) == block_after:  # mid-batch: wait here for the SIGKILL
        print("blocked", sorted(self.completed_press_ids())[-1], len(self.batched_press_ids()), flush=True)
        time.sleep(120)
    return path

writer.CampaignWriter.write_press = write_then_block
sys.exit(main(sys.argv[3:]))
"""


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("in_batch", [1, 9])
def test_sigkill_mid_batch_then_resume_equals_uninterrupted(features_protocol, reference, tmp_path, in_batch):
    folder = tmp_path / "campaign"
    block_after = 2 * BATCH + in_batch - 1  # two parts on disk, `in_batch` presses in the third batch
    argv = ["campaign", "run", str(features_protocol), "--dry-run", "--out", str(folder), "--no-report", "--quiet"]
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(BATCH), str(block_after), *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.split() == ["blocked", str(2 * BATCH - 1), str(in_batch)], (line, proc.stderr)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert _part_ids(folder) == {0: list(range(BATCH)), BATCH: list(range(BATCH, 2 * BATCH))}
    assert json.loads((folder / "manifest.json").read_text())["status"] == "running"
    _resume_equals_reference(folder, reference, 2 * BATCH)

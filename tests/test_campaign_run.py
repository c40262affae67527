"""Campaigns end to end: the smoke protocol as a dry run through a real pseudo-terminal, read back without the toolkit."""

import json
import re

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS

from neatskin.marlin.wirelog import read_wire_log
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.skin.network import equivalent_resistance


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("smoke") / "campaign"
    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    result = run_campaign(protocol, folder, dry_run=True, progress=False, report=False)
    return protocol, result, folder


def test_smoke_campaign_completes(smoke_run):
    protocol, result, folder = smoke_run
    assert (result.planned, result.completed, result.written_now, result.interrupted) == (12, 12, 12, False)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert manifest["counts"]["completed"] == 12 and manifest["seed"] == 7
    assert manifest["rig"]["kind"] == "dry-run" and manifest["rig"]["printer"].startswith(
        "simulated Marlin on /dev/pts/"
    )
    for key in ("layout", "wiring", "printer", "protocol"):
        assert (folder / manifest[key]["path"]).is_file()


def test_the_campaign_homes_before_its_first_move(smoke_run):
    """The simulated printer moves before homing, as stock Marlin does (test_marlin_real_vs_sim): the campaign never
    asks it to. Its preamble homes (G28, M400) and its first move goes out only once the printer acknowledged the
    M400, after the homing ended (resume and the re-home after a long pause send the same preamble)."""
    _, _, folder = smoke_run
    events = []  # (">", command) for each framed line written, ("<", "ok") for each ok read, in wire order
    for direction, data in read_wire_log(folder / "wire.log"):
        for raw in data.decode("ascii").splitlines():
            framed = re.fullmatch(r"N\d+ (.*)\*\d+", raw.strip())
            if direction == ">" and framed:
                events.append((">", framed.group(1)))
            elif direction == "<" and raw.startswith("ok"):
                events.append(("<", "ok"))
    codes = [(d, c.split()[0]) for d, c in events]
    first_move = min(codes.index((">", "G0")), codes.index((">", "G1")))
    homing = codes.index((">", "G28"))
    sync = codes.index((">", "M400"), homing)  # the preamble's M400: its ok comes when the homing is done
    assert homing < sync < first_move
    homed = sum(d == ">" for d, _ in codes[: sync + 1])  # lines written up to the M400
    assert codes[:first_move].count(("<", "ok")) >= homed  # all acknowledged before the first move was written


def test_dataset_reads_back_without_the_toolkit(smoke_run):
    protocol, _, folder = smoke_run
    pairs = [f"{p.i}_{p.j}" for p in protocol.layout.pairs]
    df = pd.read_parquet(folder / "presses.parquet")
    table = pq.read_table(folder / "presses.parquet")
    assert len(df) == table.num_rows == 12
    for column in (
        "campaign",
        "press_id",
        "position_id",
        "repeat",
        "x_mm",
        "y_mm",
        "depth_mm",
        "started_at",
        "finished_at",
        "fsr_onset_s",
        "fsr_offset_s",
        "fsr_peak_n",
        "flags",
    ):
        assert column in df.columns
    assert [c for c in df.columns if c.startswith("dR_ohm_")] == [f"dR_ohm_{p}" for p in pairs]
    assert [c for c in df.columns if c.startswith("R_ohm_")] == [f"R_ohm_{p}" for p in pairs]
    assert sorted(df.press_id) == list(range(12))
    assert df.groupby("position_id").size().tolist() == [2] * 6
    assert (df.depth_mm == 3.5).all() and (df.campaign == "smoke").all()
    assert all(len(f) == 0 for f in df["flags"]), df["flags"].tolist()
    assert (df.fsr_peak_n > 0.5).all() and (df.fsr_offset_s > df.fsr_onset_s).all()
    metadata = table.schema.metadata
    assert json.loads(metadata[b"neatskin.seed"]) == 7


def test_waveforms_recorded_per_position(smoke_run):
    _, _, folder = smoke_run
    waves = pq.read_table(folder / "waveforms").to_pandas()
    assert sorted(waves.press_id.unique()) == list(range(12))
    assert {"voltage_v", "current_a", "fsr_v"} <= set(waves.columns)
    per_press = waves.groupby("press_id").size()
    assert per_press.nunique() == 1 and per_press.iloc[0] > 10_000


def test_largest_dr_pair_is_the_pressed_channels(smoke_run):
    """For presses on a channel, the pair whose dR is largest is the pair that sees that channel most:
    the one the network solver picks when only that channel's resistance rises."""
    protocol, _, folder = smoke_run
    layout = protocol.layout
    from neatskin.rig.plan import build_plan

    features = {b.position_id: b.feature for b in build_plan(protocol).program.presses}
    df = pd.read_parquet(folder / "presses.parquet")
    dr_cols = [c for c in df.columns if c.startswith("dR_ohm_")]
    names = [c.name for c in layout.channels]
    checked = 0
    for _, row in df.iterrows():
        feature = features[row.position_id]
        if not feature.startswith("channel:"):
            continue
        k = names.index(feature.split(":", 1)[1])
        g = 1.0 / np.tile(layout.channel_resistance_ohm, (2, 1))
        g[1, k] /= 1.5
        r = equivalent_resistance(layout, g)
        expected = int(np.argmax(r[1] - r[0]))
        assert int(np.argmax(row[dr_cols].to_numpy(float))) == expected, (feature, row.x_mm, row.y_mm)
        checked += 1
    assert checked >= 4  # the smoke protocol's stratified positions put half its presses on channels


def test_physical_limit_written_for_the_dry_run(smoke_run):
    _, _, folder = smoke_run
    limit = pd.read_parquet(folder / "physical_limit.parquet")
    assert sorted(limit.position_id) == list(range(6))
    assert np.isfinite(limit.crb_mm).all() and (limit.crb_mm > 0).all()


def test_a_pandas_round_trip_still_validates(smoke_run, tmp_path):
    """A curator reads presses.parquet with pandas and writes it back unchanged: still a valid dataset
    (pandas writes large_string and, for all-empty flag lists, list<null>)."""
    import shutil

    from neatskin.datasets.validate import validate_dataset

    _, _, folder = smoke_run
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    pd.read_parquet(folder / "presses.parquet").to_parquet(copy / "presses.parquet", index=False)
    assert validate_dataset(copy) == []
    df = pd.read_parquet(copy / "presses.parquet")
    df.loc[3, "dR_ohm_1_2"] = np.nan
    df.to_parquet(copy / "presses.parquet", index=False)
    problems = validate_dataset(copy)
    assert [p.field for p in problems] == ["dR_ohm_1_2", "files_sha256"] and "NaN" in problems[0].message
    assert "damaged or edited" in problems[1].message  # the finished campaign's file was changed


def test_dataset_info_says_whether_the_dataset_is_valid(smoke_run, tmp_path, capsys):
    import shutil

    from neatskin.cli import main

    _, _, folder = smoke_run
    assert main(["dataset", "info", str(folder)]) == 0
    assert "validation            valid" in capsys.readouterr().out
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    df = pd.read_parquet(copy / "presses.parquet")
    df.loc[0, "x_mm"] = np.nan
    df.to_parquet(copy / "presses.parquet", index=False)
    assert main(["dataset", "info", str(copy)]) == 0
    assert "2 problem(s), e.g. 1 NaN/null value(s) in 'x_mm'" in capsys.readouterr().out


def test_a_dry_run_does_not_fsync_per_press(tmp_path, monkeypatch):
    """The dry run's writer: atomic renames (a process kill loses nothing) but no fsync per press; the number
    of fsyncs does not grow with the presses. The real rig builds its writer with fsync=True (rig/runner.py)."""
    import os

    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    calls = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: calls.append(fd) or real_fsync(fd))
    counts = []
    for limit in (2, 6):
        calls.clear()
        result = run_campaign(protocol, tmp_path / f"l{limit}", dry_run=True, progress=False, report=False, limit=limit)
        assert result.completed == limit
        counts.append(len(calls))
    assert counts[0] == counts[1] and counts[0] <= 8  # folder creation and manifest updates only

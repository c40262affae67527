"""`neatskin dataset ...`: each action through argparse, exit codes, and the real command line once."""

import argparse
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS, REPO

from neatskin.datasets import cli
from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.writer import CampaignWriter
from neatskin.errors import CheckFailed, DataError
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_REF = {"path": str(PROTOCOLS / "skins" / "paper.toml"), "name": "neatskin-paper"}


def run(argv):
    parser = argparse.ArgumentParser(prog="neatskin")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def make(folder, layout, seed=0, positions=8, repeats=2):
    rows = synthetic_rows(layout, positions, repeats, seed=seed, campaign=folder.name)
    create_manifest(
        folder,
        fsync=False,
        campaign=folder.name,
        seed=seed,
        layout=LAYOUT_REF,
        counts={"planned": len(rows), "completed": len(rows)},
    )
    with CampaignWriter(folder, layout.pairs, {"seed": seed}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    update_manifest(folder, fsync=False, status="complete")
    return rows


def test_info_and_validate(paper_layout, tmp_path, capsys):
    make(tmp_path / "c", paper_layout)
    assert run(["dataset", "info", str(tmp_path / "c"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["presses"], info["positions"]) == (16, 8)
    assert run(["dataset", "validate", str(tmp_path / "c")]) == 0
    assert "valid" in capsys.readouterr().out
    update_manifest(tmp_path / "c", fsync=False, counts={"completed": 3})
    with pytest.raises(CheckFailed) as failed:  # neatskin.cli prints it and exits 1 (test_real_command_exit_status)
        run(["dataset", "validate", str(tmp_path / "c")])
    assert [p.field for p in failed.value.problems] == ["counts.completed"]


def test_merge_split_export_plot(paper_layout, tmp_path, capsys):
    make(tmp_path / "a", paper_layout, seed=1)
    make(tmp_path / "b", paper_layout, seed=2)
    assert run(["dataset", "merge", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(tmp_path / "m")]) == 0
    assert "8 physical positions (merged ids 8..15)" in capsys.readouterr().out
    assert (
        run(
            [
                "dataset",
                "split",
                str(tmp_path / "m"),
                "-o",
                str(tmp_path / "s"),
                "--test-fraction",
                "0.25",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    assert "(8 presses, 4 positions)" in capsys.readouterr().out
    train = pd.read_parquet(tmp_path / "s" / "train" / "presses.parquet")
    test = pd.read_parquet(tmp_path / "s" / "test" / "presses.parquet")
    assert (len(train), len(test)) == (24, 8) and set(train.position_id).isdisjoint(test.position_id)
    assert run(["dataset", "export", str(tmp_path / "m"), "-o", str(tmp_path / "m.csv")]) == 0
    assert len(pd.read_csv(tmp_path / "m.csv")) == 32
    assert run(["dataset", "plot", str(tmp_path / "m"), "-o", str(tmp_path / "png")]) == 0
    assert sorted(p.name for p in (tmp_path / "png").iterdir()) == ["press_map.png", "sensitivity_map.png"]


def test_merge_of_mixed_layouts_is_a_data_error(paper_layout, tmp_path):
    make(tmp_path / "a", paper_layout, seed=1)
    make(tmp_path / "b", paper_layout, seed=2)
    update_manifest(tmp_path / "b", fsync=False, layout={**LAYOUT_REF, "name": "other"})
    with pytest.raises(DataError, match="allow-mixed"):
        run(["dataset", "merge", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(tmp_path / "m")])
    assert (
        run(["dataset", "merge", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(tmp_path / "m"), "--allow-mixed"])
        == 0
    )


def test_real_command_exit_status(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 3, 2)
    rows[2]["dR_ohm"] = np.full(28, np.nan)
    folder = tmp_path / "c"
    create_manifest(folder, fsync=False, layout=LAYOUT_REF)
    with CampaignWriter(folder, paper_layout.pairs, {}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
    result = subprocess.run(
        [sys.executable, "-m", "neatskin", "dataset", "validate", str(folder)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1
    lines = result.stderr.splitlines()
    assert len(lines) == 28 and all(
        line.startswith("neatskin: error: ") and "NaN/null value(s) in 'dR_ohm_" in line for line in lines
    )
    missing = subprocess.run(
        [sys.executable, "-m", "neatskin", "dataset", "info", str(tmp_path / "none")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert missing.returncode == 5 and "no such dataset" in missing.stderr

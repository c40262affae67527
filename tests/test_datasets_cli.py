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


def _cli(argv, capsys):
    """`neatskin ...` through neatskin.cli.main: (exit code, stdout, stderr lines)."""
    from neatskin.cli import main

    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err.splitlines()


def test_what_is_no_dataset_gets_one_error_naming_it_and_what_is_accepted(paper_layout, tmp_path, capsys):
    """A CSV the toolkit exported, its sidecar, an empty file, a parquet that is no press table, a campaign's manifest
    and a folder that is no campaign: every dataset command gives one error line naming the path, what it is and what
    is accepted. (validate said "[pairs]: no electrode pairs given (fix: pass layout.pairs)" for the CSV, naming no
    file; info called it corrupted; physical_limit.parquet ended in a KeyError traceback; plot of any file named a
    manifest.json beside it.)"""
    make(tmp_path / "c", paper_layout)
    assert _cli(["dataset", "export", str(tmp_path / "c"), "-o", str(tmp_path / "s.csv")], capsys)[0] == 0
    (tmp_path / "empty.parquet").write_bytes(b"")
    pd.DataFrame({"position_id": [0, 1], "crb_mm": [0.5, 0.6]}).to_parquet(tmp_path / "physical_limit.parquet")
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "notes.txt").write_text("not a campaign")
    accepted = "a campaign folder (written by `neatskin campaign run`) or its presses.parquet"
    cases = {
        tmp_path / "s.csv": ("a CSV file, not a press table", "CSV exports are for other tools"),
        tmp_path / "s.csv.metadata.json": ("the metadata sidecar of a CSV export", accepted),
        tmp_path / "empty.parquet": ("the file is empty (0 bytes)", accepted),
        tmp_path / "physical_limit.parquet": ("a parquet file without a press_id column", accepted),
        tmp_path / "c" / "manifest.json": (
            "a campaign's manifest, not its presses",
            f"give the campaign folder {tmp_path / 'c'}",
        ),
        tmp_path / "plain": ("not a campaign folder: no manifest.json, no presses.parquet", accepted),
    }
    for path, (what, fix) in cases.items():
        for argv, code in (
            (["dataset", "info", str(path)], 5),
            (["dataset", "validate", str(path)], 1),  # validate's verdict: 1 when anything is wrong
            (["dataset", "split", str(path), "-o", str(tmp_path / "split")], 5),
            (["dataset", "export", str(path), "-o", str(tmp_path / "out.parquet")], 5),
            (["dataset", "plot", str(path), "-o", str(tmp_path / "png"), "--drift"], 5),
            (["dataset", "merge", str(tmp_path / "c"), str(path), "-o", str(tmp_path / "merged")], 5),
        ):
            exit_code, out, err = _cli(argv, capsys)
            assert (exit_code, out) == (code, ""), (argv, err)
            assert len(err) == 1 and err[0].startswith(f"neatskin: error: {path}: {what}"), (argv, err)
            assert "(fix: " in err[0] and fix in err[0], (argv, err)
    assert not any((tmp_path / name).exists() for name in ("split", "out.parquet", "png", "merged"))
    # the folder the CSV came from, and its presses.parquet, are what these commands read
    assert _cli(["dataset", "validate", str(tmp_path / "c")], capsys)[0] == 0
    assert _cli(["dataset", "validate", str(tmp_path / "c" / "presses.parquet")], capsys)[0] == 0

"""Fault injection: hostile names and paths, closed pipes, and the curation traps (merge A A, one physical
position under two ids, datasets that borrow their sources' inputs, export formats, stale reports)."""

import os
import shutil
import subprocess
import sys
from datetime import datetime

import numpy as np
import pytest
from conftest import PROTOCOLS, REPO
from faults_helpers import SMOKE, run_cli_child

from neatskin.cli import main
from neatskin.datasets.curate import merge, split
from neatskin.datasets.reader import feature_matrix, read_presses
from neatskin.datasets.validate import validate_dataset
from neatskin.errors import DataError
from neatskin.rig.cli import default_campaign_folder

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out


@pytest.fixture
def reference(smoke_reference):
    return smoke_reference  # conftest: once per worker, for every module that reads it


NOW = datetime(2026, 1, 2, 3, 4, 5)


@pytest.mark.parametrize(
    ("name", "folder"),
    [
        ("../../x", "runs/x-20260102-030405"),
        ("/etc/cron.d/x", "runs/etc_cron.d_x-20260102-030405"),
        ("..", "runs/campaign-20260102-030405"),
        ("smoke", "runs/smoke-20260102-030405"),
    ],
)
def test_a_campaign_name_never_leaves_runs(name, folder):
    assert str(default_campaign_folder(name, NOW)) == folder


@pytest.mark.timeout(120)
def test_a_hostile_name_writes_inside_runs_only(tmp_path):
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, tmp_path / "p" / sub)
    protocol = tmp_path / "p" / "evil.toml"
    protocol.write_text(SMOKE.read_text().replace('name = "smoke"', 'name = "../../escaped"'))
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    done = subprocess.run(
        [sys.executable, "-m", "neatskin", "campaign", "run", str(protocol), "--dry-run", "--limit", "1", "--quiet"],
        cwd=work,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
    )
    if done.returncode == 3:  # the protocol loader may refuse such a name outright: as good
        assert "Traceback" not in done.stderr and "name" in done.stderr
    else:
        assert done.returncode == 0, done.stderr
        assert [p.name[:8] for p in (work / "runs").iterdir()] == ["escaped-"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "p"]
    assert not (tmp_path / "escaped").exists() and not list(tmp_path.glob("a/escaped*"))


def test_out_at_an_existing_file_is_a_clear_error(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("x")
    assert main(["campaign", "run", str(SMOKE), "--dry-run", "--out", str(target), "--quiet"]) == 3
    err = capsys.readouterr().err
    assert f"{target} is a file, not a campaign folder" in err and target.read_text() == "x"


@pytest.mark.timeout(60)
def test_piping_into_head_ends_quietly(reference):
    done = subprocess.run(
        f"{sys.executable} -m neatskin dataset info {reference} | head -1",
        shell=True,
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert done.stdout.startswith("path") and done.stdout.count("\n") == 1
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr


def test_one_fold_is_a_clear_error(reference, capsys):
    assert main(["baselines", str(reference), "--folds", "1", "--no-progress"]) == 3
    assert "--folds 1: a k-fold split needs at least 2 folds" in capsys.readouterr().err


def test_baselines_refuses_to_write_beside_an_old_report(reference, tmp_path, capsys):
    folder = tmp_path / "c"
    shutil.copytree(reference, folder)
    (folder / "report.md").write_text("old report\n")
    (folder / "baselines_ellipses_random.png").write_bytes(b"stale")
    assert main(["baselines", str(folder), "--split", "grouped", "--no-progress"]) == 3
    err = capsys.readouterr().err
    assert "already holds a baseline report" in err and "--overwrite" in err
    assert (folder / "baselines_ellipses_random.png").read_bytes() == b"stale"  # refused: nothing touched


def test_merge_of_a_campaign_with_itself_is_refused(reference, tmp_path):
    # the same folder spelled through this test's own folder and back up (`..`): the reference is not beside it
    # any more (conftest.shared_folder), so the way up is counted, not assumed
    spelled = tmp_path / ".." / tmp_path.name / os.path.relpath(reference, tmp_path)
    assert ".." in spelled.parts and spelled.resolve() == reference.resolve()
    with pytest.raises(DataError, match="named twice") as err:
        merge([reference, spelled], tmp_path / "m")
    assert err.value.field == "folders" and not (tmp_path / "m").exists()


@pytest.mark.timeout(120)
def test_same_seed_runs_share_physical_positions_and_the_grouped_split_does_not_leak(reference, tmp_path):
    again = tmp_path / "again"
    done = run_cli_child("none", "campaign", "run", str(SMOKE), "--dry-run", "--out", str(again), "--no-report")
    assert done.returncode == 0, done.stderr
    out = merge([reference, again], tmp_path / "m")
    df = read_presses(out)
    assert len(df) == 24 and df["position_id"].nunique() == 6  # 6 physical positions, not 12
    per_position = df.groupby("position_id")[["x_mm", "y_mm"]].nunique()
    assert (per_position == 1).all().all()
    halves = split(out, tmp_path / "s", test_fraction=0.34, seed=0)
    train, test = (read_presses(halves[k]) for k in ("train", "test"))
    train_xy = set(map(tuple, train[["x_mm", "y_mm"]].to_numpy()))
    assert not train_xy & set(map(tuple, test[["x_mm", "y_mm"]].to_numpy()))  # no spot on both sides
    _, _, groups = feature_matrix(df)
    assert np.unique(groups).tolist() == list(range(6))


def test_merged_and_split_datasets_keep_their_own_inputs(reference, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(reference, a)
    shutil.copytree(reference, b)
    out = merge([a, b], tmp_path / "m")
    halves = split(a, tmp_path / "s")
    shutil.rmtree(a)
    shutil.rmtree(b)
    assert (out / "inputs" / "layout.toml").is_file() and (out / "inputs" / "sources" / "1" / "printer.toml").is_file()
    assert validate_dataset(out) == []
    for folder in halves.values():
        assert (folder / "inputs" / "layout.toml").is_file() and validate_dataset(folder) == []


@pytest.mark.parametrize("name", ["x.xlsx", "x", "x.json"])
def test_export_writes_only_formats_it_names(reference, tmp_path, capsys, name):
    target = tmp_path / name
    assert main(["dataset", "export", str(reference), "-o", str(target)]) == 5
    assert "cannot tell the export format" in capsys.readouterr().err and not target.exists()
    assert main(["dataset", "export", str(reference), "-o", str(target), "--format", "csv"]) == 0
    assert target.read_text().startswith("campaign,press_id")


def test_info_and_validate_agree(reference, tmp_path, capsys):
    folder = tmp_path / "c"
    shutil.copytree(reference, folder)
    import pandas as pd

    df = pd.read_parquet(folder / "presses.parquet")
    df.at[0, "flags"] = ["fsr_missed"]
    df.to_parquet(folder / "presses.parquet", index=False)
    assert main(["dataset", "validate", str(folder)]) == 1
    assert main(["dataset", "info", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "validation" in out and "problem(s)" in out.split("validation", 1)[1]


@pytest.mark.parametrize("argv", [["skin", "press", "--x-mm", "10", "--y-mm", "10"], ["campaign", "check", str(SMOKE)]])
def test_a_closed_stdout_ends_quietly_with_141(argv, monkeypatch, capsys):
    """The reader left before we wrote (as `| head` does): no BrokenPipeError, the exit status of SIGPIPE."""
    import os

    read_end, write_end = os.pipe()
    os.close(read_end)
    with capsys.disabled(), open(write_end, "w") as closed:
        monkeypatch.setattr(sys, "stdout", closed)
        assert main(argv) == 141

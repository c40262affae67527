"""Campaign edges: a truncated or empty presses.parquet is restored from presses.copy.parquet by `campaign resume`
(no traceback, identical rows), whether the manifest says complete or a finalize was cut short."""

import json
import shutil

import pandas as pd
import pytest
from faults_helpers import make_reference, rows

from neatskin.cli import main


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return make_reference(tmp_path_factory)


@pytest.mark.parametrize("status", ["complete", "interrupted"])
@pytest.mark.parametrize("damage", ["truncated", "empty"])
def test_resume_restores_a_damaged_presses_parquet_from_its_copy(reference, tmp_path, capsys, caplog, damage, status):
    folder = tmp_path / "c"
    shutil.copytree(reference, folder)
    main_file = folder / "presses.parquet"
    data = main_file.read_bytes()
    main_file.write_bytes(data[: len(data) // 3] if damage == "truncated" else b"")
    if status != "complete":  # a finalize cut short after both files and their hash were written
        manifest = json.loads((folder / "manifest.json").read_text())
        manifest["status"] = status
        (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["campaign", "resume", str(folder), "--no-report"]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "error" not in captured.err
    assert any("restoring" in r.getMessage() and "presses.copy.parquet" in r.getMessage() for r in caplog.records)
    assert "12/12 presses" in captured.out
    pd.testing.assert_frame_equal(rows(folder), rows(reference))
    assert main_file.read_bytes() == (folder / "presses.copy.parquet").read_bytes()
    assert json.loads((folder / "manifest.json").read_text())["status"] == "complete"


def test_baselines_print_their_estimate_and_refuse_beyond_the_stated_maximum(reference, tmp_path, capsys):
    out = tmp_path / "report"
    argv = ["baselines", str(reference), "--out", str(out), "--no-progress", "--models", "ridge,knn"]
    assert main([*argv, "--max-hours", "1e-9"]) == 2
    err = capsys.readouterr().err
    assert f"baselines on {reference}: estimated" in err and "[--yes]" in err and "Traceback" not in err
    assert not (out / "report.md").exists() and not list(out.glob("*.png")) if out.exists() else True
    assert main([*argv, "--max-hours", "1e-9", "--yes", "--repeats", "2"]) == 0
    assert (out / "report.md").is_file()

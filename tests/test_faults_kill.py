"""Fault injection: SIGKILL at every stage of a campaign (folder creation, rig, presses, finalize, physical limit,
the `complete` mark, the report); what is left is always a folder that `resume` completes identically, or no
folder at all, and `dataset info` tells the crash from a running campaign."""

import json

import pandas as pd
import pytest
from faults_helpers import SMOKE, rows, run_cli_child, waveforms

from neatskin.cli import main
from neatskin.datasets.curate import describe
from neatskin.datasets.validate import validate_dataset
from neatskin.rig.runner import resume_campaign

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out


@pytest.fixture
def reference(smoke_reference):
    return smoke_reference  # conftest: once per worker, for every module that reads it


def _killed(stage, folder, *extra):
    done = run_cli_child(stage, "campaign", "run", str(SMOKE), "--dry-run", "--out", str(folder), "--quiet", *extra)
    assert done.returncode == -9, (done.returncode, done.stderr)  # SIGKILL
    return done


@pytest.mark.timeout(120)
def test_kill_during_folder_creation_leaves_no_campaign_folder(tmp_path):
    folder = tmp_path / "c"
    _killed("folder-creation", folder, "--no-report")
    assert not folder.exists()
    staging = [p.name for p in tmp_path.iterdir()]
    assert len(staging) == 1 and staging[0].startswith(".c.staging-")  # hidden, ignored, cleaned by the next run
    assert main(["campaign", "run", str(SMOKE), "--dry-run", "--out", str(folder), "--quiet", "--no-report"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["c"]
    assert len(rows(folder)) == 12


@pytest.mark.timeout(180)
@pytest.mark.parametrize(
    ("stage", "durable_presses"),
    [("rig-open", 0), ("presses", 5), ("finalize", 12), ("physical-limit", 12), ("complete", 12)],
)
def test_kill_at_a_stage_then_resume_equals_uninterrupted(reference, tmp_path, stage, durable_presses):
    folder = tmp_path / "c"
    _killed(stage, folder, "--no-report")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "running"  # the process died: nothing could say otherwise ...
    info = describe(folder) if durable_presses else None
    if info is not None:  # ... but the lock does: no live process holds it
        assert info["status"].startswith("crashed") and "resume" in info["status"]
        assert info["presses"] == durable_presses

    result = resume_campaign(folder, progress=False, report=False)
    assert (result.completed, result.written_now) == (12, 12 - durable_presses)
    assert json.loads((folder / "manifest.json").read_text())["status"] == "complete"
    assert (folder / "physical_limit.parquet").is_file() and not list((folder / "presses").iterdir())
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)
    pd.testing.assert_frame_equal(waveforms(folder), waveforms(reference), check_exact=True)
    assert validate_dataset(folder) == []


@pytest.mark.timeout(120)
def test_kill_during_the_report_then_resume_writes_the_report(reference, tmp_path, monkeypatch):
    folder = tmp_path / "c"
    _killed("report", folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "complete" and "report" not in manifest  # the data is done, the report is not
    assert not (folder / "report.md").exists()

    made = []

    def fake_report(dataset, **kwargs):  # the real report takes a minute; the runner's part is what is tested
        made.append(dataset)
        (dataset / "report.md").write_text("report\n")
        return "the report"

    monkeypatch.setattr("neatskin.baselines.report.run_baselines", fake_report)
    monkeypatch.setattr("neatskin.baselines.summary.report_summary", lambda report: f"summary of {report}")
    result = resume_campaign(folder, progress=False, report=True)
    assert (result.completed, result.written_now, made) == (12, 0, [folder])
    assert result.report_summary == "summary of the report"  # handed to the CLI to print
    assert json.loads((folder / "manifest.json").read_text())["report"]["path"] == "report.md"
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)
    with pytest.raises(Exception, match="already complete"):
        resume_campaign(folder, progress=False, report=True)


@pytest.mark.timeout(120)
def test_campaign_finish_writes_a_missing_physical_limit(reference, tmp_path):
    import shutil

    folder = tmp_path / "c"
    shutil.copytree(reference, folder)
    limit = (folder / "physical_limit.parquet").read_bytes()
    (folder / "physical_limit.parquet").unlink()
    assert main(["campaign", "finish", str(folder), "--no-report", "--quiet"]) == 0
    assert (folder / "physical_limit.parquet").read_bytes() == limit

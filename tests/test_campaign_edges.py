"""Campaign edges: a truncated or empty presses.parquet is restored from presses.copy.parquet by `campaign resume`
(no traceback, identical rows), whether the manifest says complete or a finalize was cut short."""

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from faults_helpers import rows

from neatskin.cli import main


@pytest.fixture
def reference(smoke_reference):
    """The shared smoke reference run (conftest; this module made its own copy of the same run before)."""
    return smoke_reference


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
    assert main([*argv, "--max-hours", "1e-9"]) == 3  # a configuration error (the estimate is refused)
    err = capsys.readouterr().err
    assert f"baselines on {reference}: estimated" in err and "[--yes]" in err and "Traceback" not in err
    assert not (out / "report.md").exists() and not list(out.glob("*.png")) if out.exists() else True
    assert main([*argv, "--max-hours", "1e-9", "--yes", "--repeats", "2"]) == 0
    assert (out / "report.md").is_file()


def test_the_rig_time_figures_say_what_they_are_and_agree(capsys):
    import re

    from conftest import PROTOCOLS

    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import CampaignResult, build_plan
    from neatskin.rig.summarytext import run_summary as _summary

    smoke = PROTOCOLS / "smoke.toml"
    assert main(["campaign", "check", str(smoke)]) == 0
    out = capsys.readouterr().out
    plan = build_plan(load_protocol(smoke))
    minutes = f"{plan.printer_time_s / 60:.1f}"  # under 10 minutes: in minutes, to a tenth
    assert 60 < plan.printer_time_s < 597
    assert f"printer time {minutes} min for the 12 presses (motion and holds from the G-code machine model" in out
    bound = re.search(r"rig time <= ([0-9.]+) h \(a bound from the protocol alone", out)
    assert bound is not None and float(bound.group(1)) * 60 >= float(minutes)  # the bound bounds the estimate
    done = CampaignResult(Path("c"), 12, 12, 12, 0, False, 2.0, plan.printer_time_s, None)
    assert f"printer time {minutes} min for the 12 presses written now (motion and holds" in _summary(done)
    half = CampaignResult(Path("c"), 12, 12, 6, 0, False, 2.0, plan.printer_time_s, None)
    assert f"printer time {plan.printer_time_s / 2:.0f} s for the 6 presses written now" in _summary(half)  # < 1 min


def test_the_run_summary_gives_a_slow_printers_wall_time_ratio_to_two_figures():
    """A real printer's run (0.6 of its wall time was printer time) read `0x this wall time`."""
    from neatskin.rig.summarytext import times_text as _times

    assert [_times(r) for r in (0.6, 0.0449, 2.54, 33.4, 150.0, float("inf"))] == [
        "0.6x",
        "0.045x",
        "2.5x",
        "33x",
        "150x",
        "infx",
    ]

"""`neatskin design validate`: the study's learned error beside a dry-run campaign + baselines kNN, in report.md."""

from __future__ import annotations

import re

import pytest

from neatskin.cli import main
from neatskin.design.study import load_study
from neatskin.design.validate import SECTION, validate_study, write_section

STUDY = "protocols/studies/grid5.toml"


def test_write_section_replaces_its_own_section_and_keeps_the_others(tmp_path):
    report = tmp_path / "report.md"
    report.write_text("# Study\n\n## Pareto front\n\nfront\n\n" + SECTION + "\n\nold\n\n## Later\n\nkept\n")
    write_section(report, SECTION + "\n\nnew\n\n")
    text = report.read_text()
    assert text == "# Study\n\n## Pareto front\n\nfront\n\n" + SECTION + "\n\nnew\n\n## Later\n\nkept\n"


def test_write_section_creates_the_report(tmp_path):
    write_section(tmp_path / "sub" / "report.md", SECTION + "\n\nbody\n")
    assert (tmp_path / "sub" / "report.md").read_text() == SECTION + "\n\nbody\n"


@pytest.mark.slow
def test_tiny_validation_writes_both_estimates_and_they_agree(tmp_path, capsys):
    (tmp_path / "report.md").write_text("# grid5\n\n## Pareto front\n\nfront\n")
    v = validate_study(load_study(STUDY), tmp_path, positions=15, repeats=2, split_repeats=3, folds=3)
    assert v.positions == 15 and v.repeats == 2 and v.rows == 30 and v.split_repeats == 3
    for value in (v.study_mean_mm, v.campaign_mean_mm, v.own_mean_mm):
        assert 0.0 < value < 60.0  # a finite error of skin scale (the paper skin is 30 mm square)
    assert v.campaign_std_mm > 0.0 and v.study_std_mm > 0.0
    assert v.campaign_low_mm <= v.campaign_mean_mm <= v.campaign_high_mm
    # the study's noise model is the DAQ's to within a factor 2 (median per-pair std, ohm)
    assert 0.5 < v.study_noise_ohm / v.campaign_noise_ohm < 2.0
    # measured, not loosened: on the same rows and splits the two agree, within the spread and paired
    assert v.agree
    assert v.paired_max_difference_mm < 0.1
    text = (tmp_path / "report.md").read_text()
    assert text.startswith("# grid5\n\n## Pareto front\n\nfront\n")
    assert text.count(SECTION) == 1
    section = text[text.index(SECTION) :]
    assert f"| {v.study_mean_mm:.4f} | {v.study_std_mm:.3f} |" in section
    assert f"| {v.campaign_mean_mm:.4f} | {v.campaign_std_mm:.3f} |" in section
    assert "agree within 2 combined std" in section and "What still differs" in section

    # the CLI reuses the finished dry run and rewrites the one section
    assert (
        main(
            [
                "design",
                "validate",
                STUDY,
                "--out",
                str(tmp_path),
                "--positions",
                "15",
                "--repeats",
                "2",
                "--split-repeats",
                "3",
                "--folds",
                "3",
                "--no-progress",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert re.search(rf"full pipeline \(dry run\):\s+{v.campaign_mean_mm:.4f} \+- ", out)
    assert (tmp_path / "report.md").read_text().count(SECTION) == 1
    assert sorted(p.name for p in (tmp_path / "validation").iterdir() if p.name.startswith("campaign")) == [
        "campaign-15x2"
    ]


def test_a_study_rerun_after_validate_keeps_its_section(tmp_path):
    # the worked study's committed report once lost it this way: `design study` rewrote report.md whole
    from neatskin.design.runner import run_study
    from neatskin.design.study import study_from_dict

    study = study_from_dict(
        {
            "study": {"name": "tiny", "press_grid": 4},
            "layouts": {"sizes": [[3, 3]]},
            "electrodes": {"counts": [4], "strategies": ["boundary"]},
        }
    )
    run_study(study, tmp_path, pngs=False)
    first = (tmp_path / "report.md").read_text()
    assert SECTION not in first
    write_section(tmp_path / "report.md", SECTION + "\n\nmeasured\n")
    validated = (tmp_path / "report.md").read_text()
    assert validated == first.rstrip("\n") + "\n\n" + SECTION + "\n\nmeasured\n"
    run_study(study, tmp_path, pngs=False)
    assert (tmp_path / "report.md").read_text() == validated

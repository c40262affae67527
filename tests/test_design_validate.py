"""`neatskin design validate`: the study against simulated campaigns that are not its own (exit 0, "agree"), the
negative control (exit 1, "disagree"), the ranking rule, and report.md keeping its section."""

from __future__ import annotations

import numpy as np
import pytest

from neatskin.cli import main
from neatskin.design.validate import SECTION, CandidateCheck, ranking, write_section

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


def test_the_study_agrees_with_campaigns_and_the_negative_control_disagrees(tmp_path, capsys):
    """The worked study against simulated campaigns that are not its own: exit 0 and "agree"; the campaigns' pinch
    x 0.6 (the negative control): exit 1 and "disagree", through the transfer check (the learned error alone
    barely moves). Each run is a few tens of seconds on 2 cores."""
    (tmp_path / "report.md").write_text("# grid5\n\n## Pareto front\n\nfront\n")
    assert main(["design", "validate", STUDY, "--out", str(tmp_path), "--no-power", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "verdict: agree" in out and out.count("| agree | agree |") == 4
    text = (tmp_path / "report.md").read_text()
    assert text.startswith("# grid5\n\n## Pareto front\n\nfront\n") and text.count(SECTION) == 1
    assert main(["design", "validate", STUDY, "--out", str(tmp_path), "--negative-control", "--no-power"]) == 1
    out = capsys.readouterr().out
    assert "disagree" in out and "verdict (campaigns' pinch x 0.6): disagree" in out
    assert out.count("| disagree |") == 4  # every candidate's transfer check
    text = (tmp_path / "report.md").read_text()
    assert text.count(SECTION) == 1 and "negative control: the campaigns' skin has its pinch x 0.6" in text


TINY_STUDY = """
[study]
name = "tiny"
press_grid = 4

[layouts]
sizes = [[3, 3]]

[electrodes]
counts = [4, 6, 8]
strategies = ["boundary"]

[learned]
positions = 40
repeats = 2
seeds = 2
"""


def test_validate_shows_its_progress_on_stderr_and_the_same_results_without_it(tmp_path, capsys, monkeypatch):
    """grid5's validation ran ~17 s with nothing on stderr. Now a bar counts its steps on stderr (3 candidates, the
    power sweep's study side and its 2 scales here: 6), -q turns it off, and the results stay in order: the bar's
    run on 2 processes (joblib's ordered generator) prints and writes byte for byte what a quiet run on one does."""
    import neatskin.design.validate as validate

    monkeypatch.setattr(validate, "POWER_SCALES", (0.7, 1.3))
    study = tmp_path / "tiny.toml"
    study.write_text(TINY_STUDY)
    code = main(["design", "validate", str(study), "--out", str(tmp_path / "bar"), "--jobs", "2"])
    shown = capsys.readouterr()
    assert main(["design", "validate", str(study), "--out", str(tmp_path / "quiet"), "--jobs", "1", "-q"]) == code
    quiet = capsys.readouterr()
    assert "validate tiny" in shown.err and "6/6" in shown.err and "check/s" in shown.err
    assert quiet.err == ""
    assert "verdict" in shown.out and "power" in shown.out
    assert shown.out.replace(str(tmp_path / "bar"), "OUT") == quiet.out.replace(str(tmp_path / "quiet"), "OUT")
    assert (tmp_path / "bar" / "report.md").read_bytes() == (tmp_path / "quiet" / "report.md").read_bytes()
    steps = []
    from neatskin.design.study import load_study

    validate.validate_study(load_study(study), power=False, n_jobs=1, progress=lambda *a: steps.append(a))
    assert steps == [(0, 3), (1, 3), (2, 3), (3, 3)]


def test_the_ranking_check_fails_when_the_campaigns_reverse_a_pair_the_study_separates():
    def check(label, study, scene):
        values = np.array(study), np.array(scene)
        return CandidateCheck(label, values[0], values[0], values[0], values[1])

    a = check("a", [1.0, 1.1, 0.9], [3.0, 3.1, 2.9])
    b = check("b", [2.0, 2.1, 1.9], [2.0, 2.1, 1.9])  # the study puts a first, the campaigns b, both beyond 2 SE
    c = check("c", [3.0, 3.1, 2.9], [4.0, 4.1, 3.9])
    agrees, tau = ranking([a, b, c])
    assert not agrees and tau == pytest.approx(1 / 3)
    agrees, tau = ranking([check("a", [1.0, 1.1, 0.9], [1.0, 1.1, 0.9]), b, c])
    assert agrees and tau == pytest.approx(1.0)


def test_a_study_without_three_fixed_placements_is_refused():
    from neatskin.design.study import study_from_dict
    from neatskin.design.validate import validation_candidates
    from neatskin.errors import ConfigError

    study = study_from_dict(
        {
            "study": {"name": "tiny", "press_grid": 4},
            "layouts": {"sizes": [[3, 3]]},
            "electrodes": {"counts": [4], "strategies": ["boundary"]},
        }
    )
    with pytest.raises(ConfigError, match="at least 3"):
        validation_candidates(study)


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


@pytest.mark.slow
def test_the_negative_controls_power_is_about_the_studys_own_pinch():
    """Power belongs to the check, not to the campaigns a run presses: under the negative control (pinch x 0.6)
    a 5 % change of the study's pinch stays undetected, as in the plain run (the sweep once scaled the weakened
    pinch, 0.6 x 0.95, and called every change detected). About 15 s on 2 cores."""
    from neatskin.design.study import load_study
    from neatskin.design.validate import validate_study

    v = validate_study(load_study(STUDY), pinch_scale=0.6, power=True, n_jobs=2)
    assert not v.agree
    found = dict(v.power)
    assert not found[0.95] and not found[1.05] and found[0.7]


def test_the_power_sweep_builds_the_studys_side_once_and_matches_the_full_check(tmp_path, monkeypatch):
    """The power sweep's scales share one study side (the study's learned error and its trained kNN do not depend
    on the campaigns' pinch): per run the study side is built once per candidate plus once for the sweep, not once
    per scale; and the sweep's shortened check (no protocol-scene campaigns, which it does not read) gives the
    full check's numbers. Equalities and counts of calls, whatever the study's size: on the tiny study (3 x 3,
    40 positions x 2), not grid5 (5 x 5, 200 x 4 and 4 candidates), which made this test 3 to 4 times longer."""
    import neatskin.design.learned as learned
    import neatskin.design.validate as validate
    from neatskin.design.study import load_study
    from neatskin.rig.protocol import load_protocol

    (tmp_path / "tiny.toml").write_text(TINY_STUDY)
    study = load_study(tmp_path / "tiny.toml")
    base = load_protocol("protocols/paper.toml")
    probe = validate.validation_candidates(study)[0]
    full = validate.check_candidate(study, base, probe, 0.7, 2)
    short = validate.check_candidate(
        study, base, probe, 0.7, 2, validate.study_side(study, probe), protocol_scene=False
    )
    for name in ("study_mm", "campaign_mm", "transfer_mm"):
        np.testing.assert_array_equal(getattr(short, name), getattr(full, name))
    assert len(full.scene_mm) == 2 and len(short.scene_mm) == 0
    assert (short.level_agrees, short.transfer_agrees) == (full.level_agrees, full.transfer_agrees)

    calls = []
    real = learned.learned_error_mm
    monkeypatch.setattr(learned, "learned_error_mm", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(validate, "POWER_SCALES", (0.95, 0.7, 1.3))
    v = validate.validate_study(study, power=True, n_jobs=1)
    assert len(calls) == len(v.checks) + 1  # was len(v.checks) + len(POWER_SCALES)
    assert [s for s, _ in v.power] == [0.95, 0.7, 1.3]

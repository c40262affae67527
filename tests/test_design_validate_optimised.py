"""`design validate` checks the study's optimised placements when the study's run made them in OUT (the same study:
its study.json fingerprint), leaves them out with one line saying why and how to make them when that run is absent,
unfinished or of another config, and its study column is the study's own learned error (the same computation)."""

from __future__ import annotations

import dataclasses

import pytest

from neatskin.cli import main
from neatskin.design.runner import run_study
from neatskin.design.study import load_study
from neatskin.design.validate import Validation, validate_study
from neatskin.design.validateset import label, validation_set
from neatskin.design.validatetext import verdict_lines

TINY = """
[study]
name = "tiny"
press_grid = 4

[layouts]
sizes = [[3, 3]]

[electrodes]
counts = [4, 6, 8]
strategies = ["boundary", "optimised"]
restarts = 2

[learned]
enabled = true
positions = 40
repeats = 2
seeds = 2
"""


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny study (3 x 3, boundary and optimised at 4, 6, 8 electrodes) run once into a folder."""
    root = tmp_path_factory.mktemp("tiny")
    path = root / "tiny.toml"
    path.write_text(TINY)
    study = load_study(path)
    frame = run_study(study, root / "out", jobs=1, pngs=False)
    return study, root / "out", frame


def _nodes(text: str) -> set[tuple[int, int]]:
    return {(int(i), int(j)) for i, j in (n.split(",") for n in text.split(";"))}


def test_validate_picks_up_the_runs_optimised_placements_and_reports_the_studys_own_learned_error(tiny_run):
    study, out, frame = tiny_run
    v = validate_study(study, power=False, n_jobs=1, out=out)
    rows = {f"{r.placement.rstrip('-')} {r.electrodes}": r for r in frame.itertuples()}
    boundary = {n: _nodes(rows[f"boundary {n}"].electrode_nodes) for n in (4, 6, 8)}
    optimised = {n: _nodes(rows[f"optimised {n}"].electrode_nodes) for n in (4, 6, 8)}
    new = [n for n in (4, 6, 8) if optimised[n] != boundary[n]]
    same = [n for n in (4, 6, 8) if optimised[n] == boundary[n]]
    # on the 3 x 3 grid the best 8 is the boundary ring (docs/design.md, brute force); 4 and 6 move off it
    assert new == [4, 6] and same == [8]
    labels = [c.label for c in v.checks]
    assert labels == ["boundary 4", "boundary 6", "boundary 8"] + [f"optimised {n}" for n in new]
    # every check's study column is the study's learned error in candidates.parquet, seed for seed the same numbers
    for check in v.checks:
        row = rows[check.label]
        assert check.study_mm.mean() == pytest.approx(row.learned_error_mean_mm, rel=1e-12)
        assert check.study_mm.std(ddof=1) == pytest.approx(row.learned_error_std_mm, rel=1e-12)
    # optimised against boundary at each count the optimiser changed, with the paired differences
    pairs = {(h.optimised.label, h.boundary.label) for h in v.head_to_head}
    assert pairs == {(f"optimised {n}", f"boundary {n}") for n in new}
    for h in v.head_to_head:
        d, _ = h.study_diff_mm
        assert d == pytest.approx(h.optimised.study_mm.mean() - h.boundary.study_mm.mean())
    assert v.note == "optimised 8 is boundary 8's placement (not repeated)"


def test_validate_leaves_the_optimised_placements_out_with_one_line_when_the_run_is_absent_or_stale(tiny_run, tmp_path):
    study, out, _ = tiny_run
    absent = validation_set(study, tmp_path / "empty")
    assert [c.strategy for c in absent.candidates] == ["boundary"] * 3
    assert absent.note is not None and "\n" not in absent.note and "left out" in absent.note
    assert f"neatskin design study {study.source} --out {tmp_path / 'empty'}" in absent.note
    # the same folder read by a study of another config (another seed): its placements are not this study's
    other = dataclasses.replace(study, seed=study.seed + 1)
    stale = validation_set(other, out)
    assert [c.strategy for c in stale.candidates] == ["boundary"] * 3
    assert stale.note is not None and "another study config (changed: seed)" in stale.note and "NEW_DIR" in stale.note
    # an unfinished run: the optimised parts not yet written are named as left out, the others are checked
    partial = tmp_path / "partial"
    (partial / "parts").mkdir(parents=True)
    (partial / "study.json").write_bytes((out / "study.json").read_bytes())
    for part in (out / "parts").glob("*.parquet"):
        if "optimised4" not in part.name:
            (partial / "parts" / part.name).write_bytes(part.read_bytes())
    v = validation_set(study, partial)
    assert "optimised 4" not in [label(c) for c in v.candidates]
    assert v.note is not None and "optimised 4 left out: not yet computed" in v.note
    # a committed result without its parts: study.json and candidates.parquet are enough
    committed = tmp_path / "committed"
    committed.mkdir()
    for item in ("study.json", "candidates.parquet"):
        (committed / item).write_bytes((out / item).read_bytes())
    assert validation_set(study, committed) == validation_set(study, out)
    assert any(c.strategy == "optimised" for c in validation_set(study, committed).candidates)
    assert validation_set(study, None).note == "the optimised candidates are left out: no study folder given"


def test_the_cli_prints_the_head_to_head_and_the_negative_control_still_disagrees(tiny_run, capsys):
    study, out, _ = tiny_run
    code = main(["design", "validate", study.source, "--out", str(out), "--no-power", "--jobs", "1", "-q"])
    shown = capsys.readouterr().out
    assert code == 0 and "verdict: agree" in shown
    assert "optimised 4 against boundary 4" in shown and "optimised 6 against boundary 6" in shown
    assert "note: optimised 8 is boundary 8's placement (not repeated)" in shown
    assert "paired seeds" in shown
    text = (out / "report.md").read_text()
    assert "and its optimised placements from its run" in text and "against boundary" in text
    # the negative control still disagrees, on the optimised candidates' transfer checks too
    code = main(
        ["design", "validate", study.source, "--out", str(out), "--no-power", "--jobs", "1", "-q", "--negative-control"]
    )
    shown = capsys.readouterr().out
    assert code == 1 and "verdict (campaigns' pinch x 0.6): disagree" in shown
    assert shown.count("| agree | disagree |") == 5
    assert "| optimised 4 |" in shown and "| optimised 6 |" in shown


def test_the_note_is_one_line_of_the_verdict():
    v = Validation((), 1.0, True, 1.0, (), note="the optimised candidates are left out: why")
    assert verdict_lines(v)[0] == "note: the optimised candidates are left out: why"

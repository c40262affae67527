"""Hostile design-study files: names that are paths, empty files, absurd sizes; the cost estimate and its limit;
progress within a candidate."""

import os
from pathlib import Path

import pytest

from neatskin.cli import main
from neatskin.design.study import Study, load_study, study_out_dir
from neatskin.errors import ConfigError

TINY = """
[study]
name = "NAME"
press_grid = 4

[layouts]
sizes = [[3, 3]]
pitch_mm = [15.0]

[electrodes]
counts = [4]
strategies = ["boundary"]

[probes]
diameter_mm = [5.5]
depth_mm = [3.5]
"""


def _study_file(folder: Path, name: str) -> Path:
    path = folder / "study.toml"
    text = TINY.replace('"NAME"', '"' + name.replace("\\", "\\\\").replace("\n", "\\n") + '"')
    path.write_text(text, encoding="utf-8")
    return path


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.mark.parametrize(
    "name", ["../../../../escaped", "/tmp/escaped-abs", "..", ".", "a/b", "two\nlines", "..\\x", ".hidden"]
)
def test_a_study_name_that_is_a_path_is_refused_naming_file_field_and_fix(tmp_path, name):
    path = _study_file(tmp_path, name)
    with pytest.raises(ConfigError) as info:
        load_study(path)
    (problem,) = info.value.problems
    assert problem.file == str(path) and problem.field == "study.name"
    assert "never a path" in str(problem) and problem.fix


def test_a_study_named_escaped_writes_nothing_outside_the_output_folder(tmp_path, monkeypatch, capsys):
    work = tmp_path / "a" / "b" / "c" / "d"
    work.mkdir(parents=True)
    path = _study_file(tmp_path, "../../../../escaped")
    before = _tree(tmp_path)
    monkeypatch.chdir(work)
    assert main(["design", "study", str(path), "--no-progress", "--no-png"]) == 3  # a configuration error
    assert "study.name" in capsys.readouterr().err
    assert _tree(tmp_path) == before  # nothing written anywhere, inside or out


def test_the_default_folder_is_checked_resolved_even_for_a_study_built_in_python(tmp_path):
    root = tmp_path / "out" / "design"
    root.mkdir(parents=True)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    os.symlink(outside, root / "linked")  # a planted link: the name is clean, its folder is not inside
    for name in ("../../escaped", "linked"):
        with pytest.raises(ConfigError) as info:
            study_out_dir(Study(name=name, source="s.toml"), None, root)
        assert info.value.field == "study.name"
    assert study_out_dir(Study(name="fine", source="s.toml"), None, root) == root / "fine"
    assert study_out_dir(Study(name="linked", source="s.toml"), tmp_path / "mine", root) == tmp_path / "mine"


def test_a_default_name_from_a_strange_file_stem_is_a_name(tmp_path):
    path = tmp_path / ".my study\tv2.toml"
    path.write_text(TINY.replace('name = "NAME"\n', ""), encoding="utf-8")
    assert load_study(path).name == "my_study_v2"


def test_an_empty_study_file_is_refused_not_run_as_the_default_study(tmp_path, capsys):
    path = tmp_path / "empty.toml"
    path.write_text("# nothing yet\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_study(path)
    assert info.value.file == str(path) and "empty" in str(info.value) and "grid5.toml" in str(info.value)
    assert main(["design", "study", str(path), "--out", str(tmp_path / "out")]) == 3  # a configuration error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("value", "words"), [("1e-300", "is below 0.5"), ("1e300", "is above 1000"), ("0.0", "is below 0.5")]
)
def test_an_absurd_pitch_is_refused_with_its_plausible_range(tmp_path, value, words):
    path = tmp_path / "study.toml"
    path.write_text(TINY.replace('"NAME"', '"p"').replace("[15.0]", f"[{value}]"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_study(path)
    (problem,) = info.value.problems
    assert problem.field == "layouts.pitch_mm[0]" and words in problem.message
    assert "0.5" in (problem.fix or "") and "1000" in (problem.fix or "")


TWO = TINY.replace("counts = [4]", "counts = [4, 6]").replace("press_grid = 4", "press_grid = 12")


def _study(tmp_path: Path, text: str, name: str = "two"):
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace('"NAME"', f'"{name}"'), encoding="utf-8")
    return path, load_study(path)


@pytest.mark.parametrize("jobs", [1, 2])
def test_progress_ticks_within_each_candidate_and_adds_up_to_the_candidates(tmp_path, jobs):
    from neatskin.design.runner import run_study

    _, study = _study(tmp_path, TWO.replace("[probes]", "[inversion]\nenabled = true\nlibrary = 8\n\n[probes]"))
    shares: list[float] = []
    run_study(study, tmp_path / "out", jobs=jobs, tick=shares.append, pngs=False)
    assert len(shares) >= 2 * 5  # per tile of presses and per inversion step, not per candidate
    assert sum(shares) == pytest.approx(2.0, abs=1e-9)
    assert all(0 < s < 1 for s in shares)


def test_the_default_job_count_is_the_cores_this_process_may_use(tmp_path, monkeypatch):
    from neatskin.design import runner
    from neatskin.design.runner import default_jobs, run_study

    assert default_jobs() == len(os.sched_getaffinity(0))
    seen: list[int] = []
    real = runner._joblib_results

    def spy(study, todo, jobs, tick):
        seen.append(jobs)
        return real(study, todo, jobs, tick)

    monkeypatch.setattr(runner, "_joblib_results", spy)
    _, study = _study(tmp_path, TWO)
    run_study(study, tmp_path / "out", pngs=False)
    if default_jobs() > 1:
        assert seen == [min(default_jobs(), 2)]
    else:
        assert seen == []


def test_the_estimate_is_printed_first_and_a_study_beyond_the_limit_needs_yes(tmp_path, capsys):
    path, _ = _study(tmp_path, TWO.replace("press_grid = 12", "press_grid = 10000"), "huge")
    out = tmp_path / "out"
    assert main(["design", "study", str(path), "--out", str(out), "--no-progress"]) == 3  # a configuration error
    err = capsys.readouterr().err
    first, refusal = err.strip().splitlines()[:2]
    assert first.startswith("design study huge: 2 candidate(s)") and "estimated" in first and " h " in first + " "
    assert "[--yes]" in refusal and "more than the 60 min" in refusal
    assert not out.exists()
    path, _ = _study(tmp_path, TWO, "small")
    assert main(["design", "study", str(path), "--out", str(out), "--no-progress", "--no-png", "--jobs", "1"]) == 0
    assert "design study small: 2 candidate(s) on 1 worker(s): estimated" in capsys.readouterr().err


def test_a_grid_beyond_the_dense_solve_is_refused_at_load(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(TINY.replace('"NAME"', '"s"').replace("[[3, 3]]", "[[3, 3], [10000, 10000]]"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_study(path)
    (problem,) = info.value.problems
    assert problem.field == "layouts.sizes[1]" and "100000000 junctions" in problem.message


def test_an_explicit_placement_name_is_a_name_too_as_it_names_files(tmp_path):
    text = TINY.replace('"NAME"', '"s"').replace('strategies = ["boundary"]', 'strategies = ["explicit"]')
    text += (
        '\n[[electrodes.explicit]]\nname = "../../../../escaped"\njunctions_mm = [[0, 0], [15, 0], [30, 0], [30, 15]]\n'
    )
    path = tmp_path / "s.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_study(path)
    (problem,) = info.value.problems
    assert problem.field == "electrodes.explicit[0].name" and "never a path" in problem.message


def test_the_estimate_shares_candidates_over_workers_and_scales_with_the_load(tmp_path):
    from neatskin.design.candidates import expand
    from neatskin.design.cost import candidate_seconds, slowdown, study_seconds

    _, study = _study(tmp_path, TWO)
    candidates = expand(study)
    each = [candidate_seconds(study, c) for c in candidates]
    assert study_seconds(study, candidates, 1) == pytest.approx(sum(each))
    assert study_seconds(study, candidates, 2, load=0.0, cores=2) == pytest.approx(max(sum(each) / 2, max(each)))
    assert study_seconds(study, candidates, 8, load=0.0, cores=8) == pytest.approx(max(sum(each) / 2, max(each)))
    assert slowdown(0.0, 2, 2) == 1.0 and slowdown(9.0, 2, 1) == 5.0  # one process gets 2 / 10 of a core
    loaded = study_seconds(study, candidates, 1, load=9.0, cores=2)
    assert loaded == pytest.approx(5.0 * sum(each))


def test_the_cli_bar_is_made_at_the_first_report_and_moved_by_progress_or_ticks():
    """design study and validate share one bar: made when the total is known (at the done count reported then),
    moved to each `done` when it follows (validate, a Dask study), else by a local study's ticks; none when quiet."""
    import io

    from neatskin.design.cli import _Bar

    follows = _Bar(False, unit="check", file=io.StringIO())  # the bar's text kept off the terminal
    follows.progress(0, 13)
    follows.progress(5, 13)
    assert (follows.bar.n, follows.bar.total) == (5, 13)
    ticked = _Bar(False, follow=False, file=io.StringIO())
    ticked.progress(2, 4)  # a resumed study: two candidates done before
    ticked.progress(3, 4)  # not followed: the ticks move it
    ticked.tick(0.25)
    ticked.tick(0.5)
    assert ticked.bar.n == pytest.approx(2.75)
    quiet = _Bar(True)
    quiet.progress(1, 4)
    quiet.tick(0.5)
    quiet.close()
    assert quiet.bar is None
    follows.close()
    ticked.close()

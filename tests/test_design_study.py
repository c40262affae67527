"""Design study files (validation, candidates) and local runs (joblib agrees with one process, resume after
SIGKILL of the CLI, report files)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import proctree
import pytest

from neatskin.cli import main
from neatskin.design.candidates import boundary_nodes, every_k_nodes, expand, interior_nodes
from neatskin.design.runner import run_study
from neatskin.design.study import load_study
from neatskin.errors import ConfigError
from neatskin.skin.layouts import grid_layout

REPO = Path(__file__).resolve().parent.parent

SMALL = """
[study]
name = "small"
seed = 5
press_grid = 8

[layouts]
sizes = [[3, 3], [4, 3]]
pitch_mm = [15.0]

[electrodes]
counts = [4, 6]
strategies = ["boundary", "optimised"]
restarts = 1

[probes]
diameter_mm = [5.5]
depth_mm = [3.5]
"""


def _write(tmp_path: Path, text: str, name: str = "study.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _error(tmp_path: Path, text: str) -> ConfigError:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_study(path)
    assert len(info.value.problems) == 1, info.value.problems
    assert info.value.file == str(path)
    return info.value


def test_unknown_key_gets_a_did_you_mean(tmp_path):
    err = _error(tmp_path, SMALL.replace("pitch_mm = [15.0]", "pitch_mn = [15.0]"))
    assert err.field == "layouts.pitch_mn"
    assert "did you mean 'pitch_mm'" in str(err)


def test_negative_pitch_names_the_entry(tmp_path):
    err = _error(tmp_path, SMALL.replace("pitch_mm = [15.0]", "pitch_mm = [15.0, -2.0]"))
    assert err.field == "layouts.pitch_mm[1]"
    assert "'pitch_mm' = -2.0 is below 0.5" in str(err) and "set pitch_mm to a number in mm (>= 0.5, <= 1000)" in str(
        err
    )


@pytest.mark.parametrize(
    "old, new, field, text",
    [
        ("sizes = [[3, 3], [4, 3]]", "sizes = [[3, 3], [4, 1]]", "layouts.sizes[1][1]", "'sizes' = 1 is below 2"),
        ("sizes = [[3, 3], [4, 3]]", "sizes = [3, 3]", "layouts.sizes", "'sizes' is a list of lists, got [3, 3]"),
        ('"optimised"]', '"optimized"]', "electrodes.strategies[1]", "did you mean 'optimised'?"),
        ("restarts = 1", "restarts = 1.5", "electrodes.restarts", "'restarts' must be an integer, got 1.5"),
        ("seed = 5", "seed = 5\nfidelity = 2", "study.fidelity", "'fidelity' must be a non-empty string, got 2"),
        ("[probes]", "[[probes]]", "probes", "written as an array of tables [[probes]]"),
    ],
)
def test_a_bad_entry_is_one_problem_naming_it(tmp_path, old, new, field, text):
    err = _error(tmp_path, SMALL.replace(old, new))
    assert err.field == field and text in str(err)


def test_a_sweep_may_be_one_value_and_the_schema_defaults_fill_the_rest(tmp_path):
    study = load_study(
        _write(tmp_path, SMALL.replace("pitch_mm = [15.0]", "pitch_mm = 12").replace("counts = [4, 6]", "counts = 4"))
    )
    assert study.pitch_mm == (12.0,) and study.counts == (4,) and study.sizes == ((3, 3), (4, 3))
    assert (
        study.name == "small"
        and study.channel_width_mm == (2.0,)
        and study.inversion.depth_offsets_mm == (-0.5, 0.0, 0.5)
    )
    assert load_study(_write(tmp_path, "[study]\nseed = 1\n", "bare.toml")).name == "bare"


def test_an_explicit_placement_listing_a_junction_twice(tmp_path):
    text = SMALL.replace('strategies = ["boundary", "optimised"]', 'strategies = ["explicit"]') + (
        "\n[[electrodes.explicit]]\njunctions_mm = [[0, 0], [15, 0], [0, 0]]\n"
    )
    err = _error(tmp_path, text)
    assert err.field == "electrodes.explicit[0].junctions_mm" and "two electrodes on the same junction" in str(err)


def test_more_electrodes_than_junctions(tmp_path):
    err = _error(tmp_path, SMALL.replace("counts = [4, 6]", "counts = [4, 10]"))
    assert err.field == "electrodes.counts[1]"
    assert "10 electrodes but the 3 x 3 grid has only 9 junctions" in str(err)


def test_an_electrode_on_no_channel(tmp_path):
    text = SMALL.replace('strategies = ["boundary", "optimised"]', 'strategies = ["explicit"]') + (
        '\n[[electrodes.explicit]]\nname = "mine"\njunctions_mm = [[0, 0], [15, 0], [7.0, 3.0]]\n'
    )
    err = _error(tmp_path, text)
    assert err.field == "electrodes.explicit[0].junctions_mm[2]"
    assert "electrode at (7, 3) mm of placement 'mine' is on no channel junction" in str(err)


def test_paper_like_scene_is_reported_as_not_yet_available(tmp_path):
    err = _error(tmp_path, SMALL.replace('name = "small"', 'name = "small"\nscene = "paper-like"'))
    assert err.field == "study.scene" and "not available yet" in str(err)


def test_every_problem_at_once_and_the_cli_prints_them(tmp_path, capsys):
    text = SMALL.replace("pitch_mm = [15.0]", "pitch_mm = [-1.0]").replace("seed = 5", "sed = 5")
    path = _write(tmp_path, text)
    assert main(["design", "study", str(path), "--out", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err
    assert "[study.sed]" in err and "[layouts.pitch_mm[0]]" in err and str(path) in err
    assert not (tmp_path / "out").exists()


def test_boundary_placement_of_8_on_the_paper_grid_is_the_papers():
    nodes = boundary_nodes(3, 3, 8)
    paper = grid_layout(3, 3)
    assert [n[1] * 3 + n[0] for n in nodes] == paper.electrode_junctions.tolist()
    assert boundary_nodes(5, 5, 8) == ((2, 0), (4, 0), (4, 2), (4, 4), (2, 4), (0, 4), (0, 2), (0, 0))
    assert boundary_nodes(3, 3, 9) is None
    assert interior_nodes(5, 5, 3)[0] == (2, 2)
    assert every_k_nodes(5, 5, 2) == tuple((i, j) for j in (0, 2, 4) for i in (0, 2, 4))


def test_expand_gives_every_feasible_candidate_with_stable_ids(tmp_path):
    study = load_study(_write(tmp_path, SMALL))
    candidates = expand(study)
    assert [(c.nx, c.ny, c.strategy, c.count) for c in candidates] == [
        (3, 3, "boundary", 4),
        (3, 3, "boundary", 6),
        (3, 3, "optimised", 4),
        (3, 3, "optimised", 6),
        (4, 3, "boundary", 4),
        (4, 3, "boundary", 6),
        (4, 3, "optimised", 4),
        (4, 3, "optimised", 6),
    ]
    assert len({c.candidate_id for c in candidates}) == 8
    assert [c.candidate_id for c in expand(load_study(_write(tmp_path, SMALL)))] == [c.candidate_id for c in candidates]


def test_local_run_writes_every_file_and_joblib_agrees(tmp_path):
    study = load_study(_write(tmp_path, SMALL))
    one = run_study(study, tmp_path / "one", jobs=1, pngs=False)
    assert len(one) == 8 and one["candidate_id"].is_unique
    assert (one["pairs"] == one["electrodes"] * (one["electrodes"] - 1) // 2).all()
    # 6 electrodes: 15 pairs x (2 + 20 + 100) samples at 10 kHz
    assert one.loc[one["electrodes"] == 6, "sweep_time_s"].tolist() == [0.183] * 4
    out = tmp_path / "one"
    assert pd.read_parquet(out / "candidates.parquet").equals(one)
    for cid in one["candidate_id"]:
        assert len(pd.read_parquet(out / "maps" / f"{cid}.parquet")) == 64
    report = (out / "report.md").read_text()
    assert "Pareto" in report and (out / "pareto.png").stat().st_size > 10_000
    assert "## Boundary against optimised placement" in report
    tables = [block.splitlines() for block in report.split("\n\n") if block.startswith("|")]
    assert len(tables) == 2 and len(tables[0]) == 2 + 8 and len(tables[1]) == 2 + 4  # header, rule, rows
    for table in tables:  # every row has the header's columns
        assert len({line.count("|") for line in table}) == 1
    # the optimiser is never worse than the boundary ring under its own criterion
    for (nx, ny, count), group in one.groupby(["nx", "ny", "electrodes"]):
        by = group.set_index("strategy")["criterion_D"]
        assert by["optimised"] <= by["boundary"] + 1e-5 * abs(by["boundary"]), (nx, ny, count)
    two = run_study(study, tmp_path / "two", jobs=2, pngs=False)
    pd.testing.assert_frame_equal(one, two, check_exact=True)


def test_rerun_skips_what_is_done_and_refuses_another_study(tmp_path):
    study = load_study(_write(tmp_path, SMALL))
    first = run_study(study, tmp_path / "out", pngs=False)
    seen = []
    again = run_study(study, tmp_path / "out", pngs=False, on_result=seen.append)
    assert seen == []
    pd.testing.assert_frame_equal(first, again, check_exact=True)
    other = load_study(_write(tmp_path, SMALL.replace("press_grid = 8", "press_grid = 9"), "other.toml"))
    with pytest.raises(ConfigError, match="holds results of a different study") as info:
        run_study(other, tmp_path / "out")
    assert info.value.field == "press_grid"


@pytest.mark.slow
def test_resume_after_sigkill_of_the_cli_gives_the_same_results_without_duplicates(tmp_path):
    text = SMALL.replace("press_grid = 8", "press_grid = 14").replace("restarts = 1", "restarts = 6")
    text = text.replace("sizes = [[3, 3], [4, 3]]", "sizes = [[3, 3], [4, 3], [4, 4]]")
    path = _write(tmp_path, text)
    study = load_study(path)
    total = len(expand(study))
    reference = run_study(study, tmp_path / "reference", pngs=False)
    out = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "neatskin", "design", "study", str(path), "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd + ["--no-png"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    parts = out / "parts"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if parts.is_dir() and len(list(parts.glob("*.parquet"))) >= 2:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the study finished before it could be killed; make it bigger"
    # the tick queue's manager, forked from the CLI (its command line is the CLI's), would serve forever, and
    # joblib's loky workers would run their candidates to the end for nobody (neatskin.orphans)
    children = proctree.children(proc.pid, b"design")
    assert children, "a study over several candidates with a progress tick runs the tick queue's manager"
    workers = proctree.children(proc.pid, b"LokyProcess")
    assert workers, "the study's candidates run in joblib's worker processes"
    children += workers
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stderr.close()
    # the manager and the workers end with their parent
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and [pid for pid in children if proctree.alive(pid)]:
        time.sleep(0.1)
    assert not [pid for pid in children if proctree.alive(pid)], "the killed study's manager or workers are left"
    done_at_kill = len(list(parts.glob("*.parquet")))
    assert 2 <= done_at_kill < total
    rerun = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    resumed = pd.read_parquet(out / "candidates.parquet")
    assert len(resumed) == total and resumed["candidate_id"].is_unique
    pd.testing.assert_frame_equal(resumed, reference, check_exact=True)
    assert not list(parts.glob(".*.tmp"))


def test_explicit_paper_placement_scores_as_the_boundary_ring(tmp_path):
    """The paper's electrodes listed by hand (in another order) are the boundary-8 candidate: same numbers."""
    text = SMALL.replace('strategies = ["boundary", "optimised"]', 'strategies = ["boundary", "explicit"]')
    text = text.replace("counts = [4, 6]", "counts = [8]").replace("sizes = [[3, 3], [4, 3]]", "sizes = [[3, 3]]")
    text += (
        '\n[[electrodes.explicit]]\nname = "paper"\n'
        "junctions_mm = [[0, 0], [15, 0], [30, 0], [30, 15], [30, 30], [15, 30], [0, 30], [0, 15]]\n"
    )
    frame = run_study(load_study(_write(tmp_path, text)), tmp_path / "out", pngs=False).set_index("placement")
    assert frame.loc["paper", "electrode_nodes"] == "0,0;1,0;2,0;2,1;2,2;1,2;0,2;0,1"
    for column in ("bound_median_mm", "bound_p90_mm", "bound_mean_capped_mm", "criterion_D", "peak_voltage_v"):
        assert frame.loc["paper", column] == pytest.approx(frame.loc["boundary", column], rel=1e-9), column
    # 28 pairs x 122 samples at 10 kHz
    assert frame.loc["paper", "sweep_time_s"] == pytest.approx(0.3416)

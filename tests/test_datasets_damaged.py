"""Damaged campaign files (hostile-input audit #3, #8, #10): a manifest.json that exists but cannot be read (bytes
that are not UTF-8, a folder in its place, a loop of links, no read permission), a press part or presses.parquet
without read permission, a presses file missing a column, a truncated presses.parquet under `skin fit`. Each
command ends in one clear error naming the file (and the column) with its fix, never a traceback, and nothing on
disk changes."""

import hashlib
import os
import shutil
import subprocess
import sys

import pyarrow.parquet as pq
import pytest
import test_datasets_edges as edges
from conftest import PROTOCOLS, REPO, shared_folder

from neatskin.cli import main
from neatskin.datasets.manifest import read_manifest
from neatskin.datasets.validate import validate_dataset
from neatskin.errors import DataError

LAYOUT_PATH = PROTOCOLS / "skins" / "paper.toml"
SMOKE = PROTOCOLS / "smoke.toml"
# root reads through any mode bits: the audit's way to make it obey them is to drop those capabilities
NO_ROOT_BYPASS = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner"]


def make_campaign(folder, layout, campaign="dmg", seed=9, finalize=True):
    return edges.make_campaign(folder, layout, campaign, seed, finalize)


def snapshot(folder):
    """Every file under the folder with the sha256 of its bytes (None when it cannot be read)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            try:
                out[str(path.relative_to(folder))] = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError:
                out[str(path.relative_to(folder))] = None
    return out


def one_error(err: str) -> str:
    assert "Traceback" not in err and err.count("neatskin: error:") == 1, err
    return err.strip().splitlines()[-1]


def cli_child(*argv, root_bypass=True):
    """`neatskin ARGV` in a child process. root_bypass=False: as root, the capabilities that read and write through
    mode bits are dropped first (setpriv, as the audit ran it), so a chmod 000 file is unreadable to the child."""
    command = [sys.executable, "-m", "neatskin", *argv]
    if os.geteuid() == 0 and not root_bypass:
        if shutil.which("setpriv") is None:
            pytest.skip("root reads through mode bits and setpriv is not here to drop that")
        command = [*NO_ROOT_BYPASS, *command]
    return subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=120)


def _not_utf8(path):
    path.write_bytes(b"\xff\xfe\x00garbage")


def _a_folder(path):
    path.unlink()
    path.mkdir()


def _a_loop(path):
    path.unlink()
    path.symlink_to(path.name)  # manifest.json -> manifest.json


# ---- #3: a manifest.json that exists but cannot be read ----------------------------------------------------


@pytest.mark.parametrize(
    "damage, words",
    [
        (_not_utf8, "manifest.json is not UTF-8 text (byte 0xff at offset 0)"),
        (_a_folder, "cannot read the file: Is a directory"),
        (_a_loop, "cannot read the file: Too many levels of symbolic links"),
    ],
)
def test_a_manifest_that_cannot_be_read_is_one_error_naming_it(paper_layout, tmp_path, capsys, damage, words):
    good = make_campaign(tmp_path / "good", paper_layout, "good", seed=1)
    folder = make_campaign(tmp_path / "c", paper_layout)
    manifest = folder / "manifest.json"
    damage(manifest)
    before = snapshot(folder)

    with pytest.raises(DataError) as err:
        read_manifest(folder)
    (problem,) = err.value.problems
    assert problem.file == str(manifest) and words in problem.message and "restore manifest.json" in problem.fix

    assert main(["dataset", "validate", str(folder)]) == 1  # the check's verdict: one line, the manifest's
    assert one_error(capsys.readouterr().err).startswith(f"neatskin: error: {manifest}: {words}")
    assert main(["dataset", "plot", str(folder), "-o", str(tmp_path / "png")]) == 5  # its layout is in the manifest
    assert words in one_error(capsys.readouterr().err) and not (tmp_path / "png").exists()
    assert main(["dataset", "merge", str(good), str(folder), "-o", str(tmp_path / "m")]) == 5
    line = one_error(capsys.readouterr().err)
    assert line.startswith(f"neatskin: error: {folder}: ") and words in line and not (tmp_path / "m").exists()
    assert main(["dataset", "info", str(folder)]) == 0  # describes the presses; its validation line names it
    assert f"1 problem(s), e.g. {words}" in capsys.readouterr().out
    for command in ("resume", "finish"):
        assert main(["campaign", command, str(folder), "--no-report"]) == 5
        assert one_error(capsys.readouterr().err).startswith(f"neatskin: error: {manifest}: {words}")
    (folder / "inputs").mkdir()
    shutil.copy(LAYOUT_PATH, folder / "inputs" / "layout.toml")
    assert main(["skin", "fit", str(folder)]) == 5
    assert str(manifest) in one_error(capsys.readouterr().err)
    shutil.rmtree(folder / "inputs")
    assert snapshot(folder) == before  # nothing written, nothing lost
    assert not (folder / "campaign.lock").exists()


def test_a_stop_is_recorded_and_the_damaged_manifest_named_as_a_warning(paper_layout, tmp_path, capsys):
    """`campaign stop` on a folder whose manifest is not UTF-8: the runner reads the request, not the manifest, so
    the stop is kept (exit 0) and the manifest's damage is a warning naming it, not a traceback after the write."""
    import json

    folder = make_campaign(tmp_path / "c", paper_layout, finalize=False)
    manifest = folder / "manifest.json"
    _not_utf8(manifest)
    assert main(["campaign", "stop", str(folder)]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and captured.err.count("neatskin: warning:") == 1
    assert captured.err.startswith(f"neatskin: warning: {manifest}: manifest.json is not UTF-8 text")
    assert f"stop requested for {folder} (campaign unknown" in captured.out and "not running" not in captured.out
    assert json.loads((folder / "control.json").read_text())["action"] == "stop"


def test_a_manifest_without_read_permission_is_one_error_naming_it(paper_layout, tmp_path):
    folder = make_campaign(tmp_path / "c", paper_layout)
    manifest = folder / "manifest.json"
    manifest.chmod(0o000)
    try:
        before = snapshot(folder)
        for argv, code in (
            (["dataset", "validate", str(folder)], 1),
            (["dataset", "plot", str(folder), "-o", str(tmp_path / "png")], 5),
            (["campaign", "resume", str(folder), "--no-report"], 5),
            (["campaign", "finish", str(folder), "--no-report"], 5),
        ):
            done = cli_child(*argv, root_bypass=False)
            line = one_error(done.stderr)
            assert done.returncode == code, done.stderr
            assert line == (
                f"neatskin: error: {manifest}: cannot read the file: Permission denied "
                f"(fix: give your user read permission on it (chmod u+r {manifest}))"
            )
        # the control: with the root bypass left in place (or as a user who may read it) the same command reads it
        if os.geteuid() == 0:
            assert cli_child("dataset", "validate", str(folder)).returncode == 0
        assert snapshot(folder) == before
    finally:
        manifest.chmod(0o644)


# ---- #3: a press part or presses.parquet without read permission ----------------------------------------------


# this module's, made once per session and read (copied) by its tests: conftest.shared_folder (module scope remade
# them whenever the suite's order came back to the module, session scope once per worker)
@pytest.fixture(scope="session")
def partial(tmp_path_factory):
    """The smoke campaign (records waveforms) stopped after 4 presses: one part per press."""

    def make(root):
        done = cli_child(
            "campaign", "run", str(SMOKE), "--dry-run", "--out", str(root / "c"), "--limit", "4", "--quiet"
        )
        assert done.returncode == 0, done.stderr

    return shared_folder(tmp_path_factory, "damaged-partial", make) / "c"


@pytest.fixture(scope="session")
def complete(tmp_path_factory):
    def make(root):
        done = cli_child("campaign", "run", str(SMOKE), "--dry-run", "--out", str(root / "c"), "--no-report", "--quiet")
        assert done.returncode == 0, done.stderr

    return shared_folder(tmp_path_factory, "damaged-complete", make) / "c"


def _assert_resume_and_finish_name_the_unreadable(folder, path) -> None:
    """`campaign resume` and `campaign finish` both stop (exit 5) with the one error naming the unreadable file."""
    for command in ("resume", "finish"):
        done = cli_child("campaign", command, str(folder), "--no-report", "--quiet", root_bypass=False)
        assert done.returncode == 5, done.stderr
        assert one_error(done.stderr) == (
            f"neatskin: error: {path}: cannot read the file: Permission denied "
            f"(fix: give your user read permission on it (chmod u+r {path}))"
        )


def test_a_part_without_read_permission_is_named_by_validate_info_resume_and_finish(partial, tmp_path):
    folder = tmp_path / "c"
    shutil.copytree(partial, folder)
    part = folder / "presses" / "part-000002.parquet"
    part.chmod(0o000)
    try:
        rows_before = {p.name: p.stat().st_size for p in (folder / "presses").iterdir()}
        done = cli_child("dataset", "validate", str(folder), root_bypass=False)
        assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
        assert (
            f"neatskin: error: {part}: unreadable parquet file:" in done.stderr and "Permission denied" in done.stderr
        )
        done = cli_child("dataset", "info", str(folder), root_bypass=False)
        assert done.returncode == 5 and str(part) in one_error(done.stderr)
        _assert_resume_and_finish_name_the_unreadable(folder, part)
        assert {p.name: p.stat().st_size for p in (folder / "presses").iterdir()} == rows_before
        assert read_manifest(folder)["status"] != "complete"
    finally:
        part.chmod(0o644)
    # after the fix the campaign completes: nothing was lost
    done = cli_child("campaign", "resume", str(folder), "--no-report", "--quiet")
    assert done.returncode == 0, done.stderr
    assert pq.read_metadata(folder / "presses.parquet").num_rows == 12


def test_a_presses_parquet_without_read_permission_is_named_by_resume_and_finish(complete, tmp_path):
    folder = tmp_path / "c"
    shutil.copytree(complete, folder)
    main_file = folder / "presses.parquet"
    (folder / "physical_limit.parquet").unlink()  # something for resume and finish to do
    main_file.chmod(0o000)
    try:
        before = snapshot(folder)
        _assert_resume_and_finish_name_the_unreadable(folder, main_file)
        done = cli_child("dataset", "validate", str(folder), root_bypass=False)
        assert done.returncode == 1 and f"{main_file}: unreadable parquet file" in done.stderr, done.stderr
        assert snapshot(folder) == before
    finally:
        main_file.chmod(0o644)
    done = cli_child("campaign", "finish", str(folder), "--no-report", "--quiet")
    assert done.returncode == 0, done.stderr
    assert (folder / "physical_limit.parquet").is_file() and cli_child(
        "dataset", "validate", str(folder)
    ).returncode == 0


# ---- #8: a presses file with a missing column ----------------------------------------------------------------


def drop_column(path, column):
    """Rewrite a press file without `column`, its metadata kept (as a pyarrow edit does)."""
    table = pq.read_table(path)
    pq.write_table(table.drop_columns([column]), path)
    assert pq.read_schema(path).metadata == table.schema.metadata


@pytest.mark.parametrize("column", ["x_mm", "y_mm", "dR_ohm_1_2", "press_id", "position_id"])
def test_every_dataset_command_refuses_a_missing_column_as_validate_names_it(paper_layout, tmp_path, capsys, column):
    healthy = make_campaign(tmp_path / "healthy", paper_layout, "healthy", seed=1)
    folder = make_campaign(tmp_path / "c", paper_layout)
    for name in ("presses.parquet", "presses.copy.parquet"):
        drop_column(folder / name, column)
    before = snapshot(folder)
    expected = (
        f"neatskin: error: {folder / 'presses.parquet'}: [{column}]: missing column(s): {column} (fix: rewrite the "
        "file with every column of the layout's schema (or validate against the layout the campaign used))"
    )
    assert main(["dataset", "validate", str(folder)]) == 1
    assert expected in capsys.readouterr().err.splitlines()  # validate's own line, the one every command gives

    outputs = {
        "info": [],
        "split": ["-o", str(tmp_path / "split")],
        "export": ["-o", str(tmp_path / "x.parquet")],
        "export-csv": ["-o", str(tmp_path / "x.csv")],
        "export-hf": ["--format", "hf", "-o", str(tmp_path / "hf")],
        "plot": ["-o", str(tmp_path / "png")],
    }
    for command, extra in outputs.items():
        assert main(["dataset", command.split("-")[0], str(folder), *extra]) == 5, command
        assert one_error(capsys.readouterr().err) == expected, command
    assert main(["dataset", "info", str(folder / "presses.parquet")]) == 5  # the file itself, not the folder
    assert one_error(capsys.readouterr().err) == expected
    for sources in ([healthy, folder], [folder, healthy]):  # the damaged folder named, first or second
        assert main(["dataset", "merge", *map(str, sources), "-o", str(tmp_path / "m")]) == 5
        assert one_error(capsys.readouterr().err) == expected
    assert not any((tmp_path / name).exists() for name in ("split", "x.parquet", "x.csv", "hf", "png", "m"))
    assert snapshot(folder) == before


def test_a_part_missing_a_column_is_refused_by_name_even_by_merge_allow_invalid(paper_layout, tmp_path, capsys):
    """An interrupted campaign whose fourth part lacks x_mm: every reader names that part with validate's line; merge
    refuses it even with --allow-invalid (it cannot place those presses) before it makes the output folder."""
    healthy = make_campaign(tmp_path / "healthy", paper_layout, "healthy", seed=1)
    folder = make_campaign(tmp_path / "c", paper_layout, finalize=False)
    part = sorted((folder / "presses").glob("part-*.parquet"))[3]
    drop_column(part, "x_mm")
    expected = (
        f"neatskin: error: {part}: [x_mm]: missing column(s): x_mm (fix: rewrite the file with every column of the "
        "layout's schema (or validate against the layout the campaign used))"
    )
    assert main(["dataset", "validate", str(folder)]) == 1
    assert expected in capsys.readouterr().err.splitlines()
    for argv in (["info", str(folder)], ["split", str(folder), "-o", str(tmp_path / "s")]):
        assert main(["dataset", *argv]) == 5
        assert one_error(capsys.readouterr().err) == expected
    merge = ["dataset", "merge", str(healthy), str(folder), "-o", str(tmp_path / "m"), "--allow-incomplete"]
    assert main([*merge, "--allow-invalid"]) == 5
    assert one_error(capsys.readouterr().err) == expected
    assert not (tmp_path / "m").exists() and not (tmp_path / "s").exists()


def test_a_campaign_on_other_pairs_is_no_missing_column(paper_layout, tmp_path):
    """The negative control: columns dropped together with their pair in the metadata are another pair set, read
    as it is (merge tells it apart by its pairs, not as damage)."""
    from neatskin.datasets.reader import read_presses
    from neatskin.datasets.schema import decode_metadata, encode_metadata

    folder = make_campaign(tmp_path / "c", paper_layout)
    path = folder / "presses.parquet"
    table = pq.read_table(path)
    meta = decode_metadata(table.schema.metadata)
    meta["pairs"] = [p for p in meta["pairs"] if p != [1, 2]]
    pq.write_table(table.drop_columns(["R_ohm_1_2", "dR_ohm_1_2"]).replace_schema_metadata(encode_metadata(meta)), path)
    df = read_presses(path)
    assert len(df) == 15 and "dR_ohm_1_2" not in df and "dR_ohm_1_3" in df


# ---- #10: skin fit on a truncated presses.parquet ------------------------------------------------------------


def test_skin_fit_on_a_truncated_presses_file_is_the_dataset_commands_error(paper_layout, tmp_path, capsys):
    folder = make_campaign(tmp_path / "c", paper_layout)
    (folder / "inputs").mkdir()
    shutil.copy(LAYOUT_PATH, folder / "inputs" / "layout.toml")
    path = folder / "presses.parquet"
    with open(path, "r+b") as handle:
        handle.truncate(path.stat().st_size // 2)
    assert main(["dataset", "split", str(folder), "-o", str(tmp_path / "s")]) == 5  # what a dataset command says
    dataset_line = one_error(capsys.readouterr().err)
    assert main(["skin", "fit", str(folder), "-o", str(tmp_path / "fit.toml")]) == 5
    line = one_error(capsys.readouterr().err)
    assert line.startswith(f"neatskin: error: {path}: cannot read the presses: ") and "magic bytes" in line
    assert line.split(": cannot read the presses: ")[1] == dataset_line.split(": cannot read the presses: ")[1]
    assert not (tmp_path / "fit.toml").exists()


# ---- #7: a waveform part deleted from a campaign that records waveforms ------------------------------------


def test_a_lost_waveform_part_is_named_and_the_campaign_is_not_completed_without_it(partial, tmp_path):
    folder = tmp_path / "c"
    shutil.copytree(partial, folder)
    (lost,) = (folder / "waveforms").glob("position_id=*/part-000002.parquet")
    lost.unlink()
    press_part = folder / "presses" / "part-000002.parquet"
    fix = f"move part-000002.parquet out of {folder / 'presses'} and resume"

    (problem,) = validate_dataset(folder)
    assert problem.file == str(lost) and problem.field == "waveforms" and "press(es) 2 " in problem.message
    assert problem.fix.startswith(fix)
    for command in ("resume", "finish"):
        done = cli_child("campaign", command, str(folder), "--no-report", "--quiet")
        assert done.returncode == 5 and f"{lost}: [waveforms]: press(es) 2 " in one_error(done.stderr), done.stderr
        assert read_manifest(folder)["status"] != "complete" and not (folder / "presses.parquet").exists()
        assert len(list((folder / "presses").glob("part-*.parquet"))) == 4  # every press kept

    press_part.rename(tmp_path / press_part.name)  # the fix: the press is pressed again, with its waveforms
    done = cli_child("campaign", "resume", str(folder), "--no-report", "--quiet")
    assert done.returncode == 0, done.stderr
    assert pq.read_metadata(folder / "presses.parquet").num_rows == 12
    assert len(list((folder / "waveforms").glob("position_id=*/part-*.parquet"))) == 12 and lost.is_file()
    assert validate_dataset(folder) == []


def test_a_waveform_part_lost_after_completion_is_named_by_validate(complete, tmp_path, capsys):
    folder = tmp_path / "c"
    shutil.copytree(complete, folder)
    assert validate_dataset(folder) == []  # the control: the campaign as it finished
    (lost,) = (folder / "waveforms").glob("position_id=*/part-000007.parquet")
    lost.unlink()
    assert main(["dataset", "validate", str(folder)]) == 1
    line = one_error(capsys.readouterr().err)
    assert line.startswith(f"neatskin: error: {lost}: [waveforms]: press(es) 7 of a campaign that records waveforms")
    assert "restore the waveform part(s) from a backup" in line


def test_an_export_it_cannot_write_says_run_the_command_again_not_resume(tmp_path, paper_layout):
    """The shared write errors end in the campaign writer's next step, "then resume"; for an export there is nothing
    to resume (hostile-input audit #14): the fix says to run the command again."""
    folder = tmp_path / "camp"
    make_campaign(folder, paper_layout)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        done = cli_child(
            "dataset", "export", str(folder), "--format", "csv", "-o", str(locked / "s.csv"), root_bypass=False
        )
    finally:
        locked.chmod(0o755)
    assert done.returncode == 5, done.stderr
    assert "chmod u+w), then run the command again)" in done.stderr and "resume" not in done.stderr
    assert "Traceback" not in done.stderr and not (locked / "s.csv").exists()

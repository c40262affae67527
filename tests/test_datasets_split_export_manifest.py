"""`dataset split` and `dataset export` (parquet, CSV, hf) on a campaign folder whose manifest.json is damaged
(truncated, not JSON, not an object, unreadable): the one DataError that validate, plot and resume give for it,
naming the manifest and how to restore it, before anything is written. Before, both read such a folder as a plain
dataset without a manifest and wrote an output that had lost the campaign's provenance and recorded host."""

import json
import os

import pytest
import test_datasets_damaged as damaged

from neatskin.cli import main
from neatskin.datasets.curate import export, split
from neatskin.datasets.manifest import read_manifest
from neatskin.errors import DataError

RESTORE = "restore manifest.json from a backup (the presses are not in it and stay as they are)"


def _truncated(path):
    text = path.read_bytes()
    path.write_bytes(text[: len(text) // 2])  # a write cut off half way


def _not_json(path):
    path.write_text("status: complete\n")


def _not_an_object(path):
    path.write_text("[1, 2, 3]")


DAMAGES = {
    "truncated": (_truncated, "manifest.json is not valid JSON: "),
    "not JSON": (_not_json, "manifest.json is not valid JSON: Expecting value: line 1 column 1 (char 0)"),
    "not an object": (_not_an_object, "manifest.json must hold a JSON object ({...}): damaged"),
}


def _outputs(tmp_path):
    """Each command with its output under tmp_path/out (nothing else there), and what it would write."""
    out = tmp_path / "out"
    return {
        "split": (["-o", str(out / "split")], [out / "split"]),
        "export": (["-o", str(out / "x.parquet")], [out / "x.parquet"]),
        "export-csv": (["-o", str(out / "x.csv")], [out / "x.csv", out / "x.csv.metadata.json"]),
        "export-hf": (["--format", "hf", "-o", str(out / "hf")], [out / "hf"]),
    }


@pytest.mark.parametrize("damage", DAMAGES, ids=str)
def test_split_and_export_stop_on_a_damaged_manifest_before_writing(paper_layout, tmp_path, capsys, damage):
    make, words = DAMAGES[damage]
    folder = damaged.make_campaign(tmp_path / "c", paper_layout)
    manifest = folder / "manifest.json"
    make(manifest)
    (tmp_path / "out").mkdir()
    before = damaged.snapshot(folder)
    with pytest.raises(DataError) as err:
        read_manifest(folder)  # the error the other commands give
    (expected,) = err.value.problems
    assert expected.file == str(manifest) and expected.message.startswith(words) and expected.fix == RESTORE

    for command, (extra, written) in _outputs(tmp_path).items():
        assert main(["dataset", command.split("-")[0], str(folder), *extra]) == 5, command
        line = damaged.one_error(capsys.readouterr().err)
        assert line == f"neatskin: error: {expected}", command
        assert not any(p.exists() for p in written), command
    assert list((tmp_path / "out").iterdir()) == []  # nothing written, not even an empty folder
    assert damaged.snapshot(folder) == before  # and nothing changed in the source

    # the Python API gives the same error
    with pytest.raises(DataError) as err:
        split(folder, tmp_path / "out" / "s")
    assert err.value.problems == (expected,) and not (tmp_path / "out" / "s").exists()
    with pytest.raises(DataError) as err:
        export(folder, tmp_path / "out" / "e.parquet")
    assert err.value.problems == (expected,) and not (tmp_path / "out" / "e.parquet").exists()


def test_the_control_a_sound_or_absent_manifest_still_splits_and_exports(paper_layout, tmp_path, capsys):
    """The negative control: the same campaign with its manifest intact splits and exports (the manifest's campaign
    carried over); without a manifest.json at all it is a plain dataset folder and still does; a lone presses file
    beside a damaged manifest exports (the file is what was asked for)."""
    folder = damaged.make_campaign(tmp_path / "c", paper_layout)
    assert main(["dataset", "split", str(folder), "-o", str(tmp_path / "s")]) == 0
    assert read_manifest(tmp_path / "s" / "train")["campaign"] == "dmg"
    assert main(["dataset", "export", str(folder), "-o", str(tmp_path / "x.parquet")]) == 0

    plain = damaged.make_campaign(tmp_path / "plain", paper_layout)
    (plain / "manifest.json").unlink()
    assert main(["dataset", "split", str(plain), "-o", str(tmp_path / "s2")]) == 0
    assert read_manifest(tmp_path / "s2" / "train")["campaign"] is None
    assert main(["dataset", "export", str(plain), "-o", str(tmp_path / "p.csv")]) == 0

    _truncated(folder / "manifest.json")
    assert main(["dataset", "export", str(folder / "presses.parquet"), "-o", str(tmp_path / "f.parquet")]) == 0
    assert (tmp_path / "f.parquet").is_file()
    capsys.readouterr()


def test_split_and_export_stop_on_a_manifest_without_read_permission(paper_layout, tmp_path):
    """chmod 000: as root, run with the capabilities that read through mode bits dropped (setpriv, skipped with the
    reason when setpriv is missing), so the child meets the permission error a user would."""
    folder = damaged.make_campaign(tmp_path / "c", paper_layout)
    manifest = folder / "manifest.json"
    (tmp_path / "out").mkdir()
    manifest.chmod(0o000)
    try:
        before = damaged.snapshot(folder)
        for command, (extra, written) in _outputs(tmp_path).items():
            done = damaged.cli_child("dataset", command.split("-")[0], str(folder), *extra, root_bypass=False)
            assert done.returncode == 5, done.stderr
            assert damaged.one_error(done.stderr) == (
                f"neatskin: error: {manifest}: cannot read the file: Permission denied "
                f"(fix: give your user read permission on it (chmod u+r {manifest}))"
            ), command
            assert not any(p.exists() for p in written), command
        assert list((tmp_path / "out").iterdir()) == []
        assert damaged.snapshot(folder) == before
        if os.geteuid() == 0:  # the control: with root's bypass the same split reads the manifest and writes
            done = damaged.cli_child("dataset", "split", str(folder), "-o", str(tmp_path / "out" / "ok"))
            assert done.returncode == 0, done.stderr
            assert json.loads((tmp_path / "out" / "ok" / "train" / "manifest.json").read_text())["campaign"] == "dmg"
    finally:
        manifest.chmod(0o644)

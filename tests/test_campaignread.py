"""The ground-floor campaign reader (neatskin.campaignread) serves both the datasets and the skin fit: one reading of
manifest.json and of a presses file, so `skin fit` and the dataset commands give the same error for the same damaged
file. Before, skin/fit.py kept its own copies (the import contract keeps skin from datasets), and a damaged manifest
was 'cannot read the manifest: <Python's text>' with another fix under `skin fit`."""

import shutil

import pytest
import test_datasets_damaged as damaged
from conftest import PROTOCOLS

import neatskin.campaignread as campaignread
import neatskin.datasets.manifest as manifest_module
import neatskin.datasets.tables as tables
from neatskin.cli import main
from neatskin.errors import DataError
from neatskin.skin.fit import load_campaign


def test_the_datasets_read_through_the_one_reader():
    assert manifest_module.read_manifest is campaignread.read_manifest
    assert tables.read_parquet is campaignread.read_parquet
    assert tables.unreadable_presses is campaignread.unreadable_presses


def _truncate(path):
    path.write_bytes(path.read_bytes()[:40])


DAMAGES = {
    "missing": (lambda p: p.unlink(), "no manifest.json in the campaign folder"),
    "not UTF-8": (damaged._not_utf8, "manifest.json is not UTF-8 text (byte 0xff at offset 0): damaged"),
    "truncated": (_truncate, "manifest.json is not valid JSON: "),
    "not an object": (lambda p: p.write_text('"complete"'), "manifest.json must hold a JSON object ({...}): damaged"),
    "a folder": (damaged._a_folder, "cannot read the file: Is a directory"),
    "a loop": (damaged._a_loop, "cannot read the file: Too many levels of symbolic links"),
}


@pytest.fixture(scope="module")
def fittable(paper_layout, tmp_path_factory):
    folder = damaged.make_campaign(tmp_path_factory.mktemp("fit") / "c", paper_layout)
    (folder / "inputs").mkdir()
    shutil.copy(PROTOCOLS / "skins" / "paper.toml", folder / "inputs" / "layout.toml")
    return folder


@pytest.mark.parametrize("damage", DAMAGES, ids=str)
def test_skin_fit_and_the_dataset_commands_give_one_error_for_a_damaged_manifest(fittable, tmp_path, capsys, damage):
    make, words = DAMAGES[damage]
    folder = tmp_path / "c"
    shutil.copytree(fittable, folder)
    make(folder / "manifest.json")
    with pytest.raises(DataError) as datasets_error:
        manifest_module.read_manifest(folder)
    (problem,) = datasets_error.value.problems
    assert problem.file == str(folder / "manifest.json") and problem.message.startswith(words)
    with pytest.raises(DataError) as fit_error:
        load_campaign(folder)
    assert fit_error.value.problems == (problem,)
    before = damaged.snapshot(folder)
    assert main(["skin", "fit", str(folder)]) == 5
    assert damaged.one_error(capsys.readouterr().err) == f"neatskin: error: {problem}"
    assert damaged.snapshot(folder) == before


def test_a_sound_campaign_loads_for_the_fit(fittable):
    """The control: the same folder undamaged loads, its manifest the one the datasets read."""
    layout, manifest, columns = load_campaign(fittable)
    assert manifest == manifest_module.read_manifest(fittable) and manifest["campaign"] == "dmg"
    assert columns["dR"].shape == (15, len(layout.pairs)) and columns["position"].tolist() == sorted(
        columns["position"].tolist()
    )


def test_a_truncated_presses_file_is_the_same_error_for_the_fit_and_the_reader(fittable, tmp_path):
    folder = tmp_path / "c"
    shutil.copytree(fittable, folder)
    presses = folder / "presses.parquet"
    _truncate(presses)
    with pytest.raises(DataError) as fit_error:
        load_campaign(folder)
    with pytest.raises(DataError) as reader_error:
        campaignread.read_presses_file(presses)
    assert fit_error.value.problems == reader_error.value.problems
    (problem,) = reader_error.value.problems
    assert problem.file == str(presses) and problem.message.startswith("cannot read the presses: ")
    assert problem.fix == "run `neatskin dataset validate` on the folder to find the damaged file"

"""Fault injection: tampering and silent corruption. A flipped bit in a committed part or in the final
presses.parquet, a renamed part, another campaign's part dropped in, a deleted input hash, a manifest whose
`rig` is a string: each is refused with a DataError naming the file (or recovered exactly), never accepted."""

import json
import shutil

import pandas as pd
import pyarrow.parquet as pq
import pytest
from faults_helpers import SMOKE, rows, run_cli_child

from neatskin.cli import main
from neatskin.datasets.validate import validate_dataset
from neatskin.errors import DataError
from neatskin.rig.runner import finish_campaign, resume_campaign

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out


@pytest.fixture
def reference(smoke_reference):
    return smoke_reference  # conftest: once per worker, for every module that reads it


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
    """The smoke campaign stopped after 4 presses (a clean --limit stop: part hashes in the manifest)."""
    folder = tmp_path_factory.mktemp("partial") / "c"
    done = run_cli_child(
        "none", "campaign", "run", str(SMOKE), "--dry-run", "--out", str(folder), "--limit", "4", "--quiet"
    )
    assert done.returncode == 0, done.stderr
    return folder


def flip_bit_in_column(path, column="x_mm"):
    """Flip one bit inside the data of `column` (the end of its column chunk, past the page header)."""
    meta = pq.ParquetFile(path).metadata.row_group(0)
    chunk = next(meta.column(k) for k in range(meta.num_columns) if meta.column(k).path_in_schema == column)
    offset = chunk.data_page_offset + chunk.total_compressed_size - 2
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def _copy(folder, tmp_path):
    target = tmp_path / "c"
    shutil.copytree(folder, target)
    return target


def _first_part(folder):
    return sorted((folder / "presses").glob("part-*.parquet"))[0]


@pytest.mark.parametrize("hash_recorded", [True, False])
def test_a_flipped_bit_in_a_committed_part_is_refused(partial, tmp_path, hash_recorded):
    folder = _copy(partial, tmp_path)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert len(manifest["parts_sha256"]) == 4
    if not hash_recorded:  # as after a kill: only the parquet page checksums can tell
        del manifest["parts_sha256"]
        (folder / "manifest.json").write_text(json.dumps(manifest))
    part = _first_part(folder)
    flip_bit_in_column(part)
    with pytest.raises(DataError) as err:
        resume_campaign(folder, progress=False, report=False)
    assert err.value.file == str(part) and f"move {part.name} out of" in err.value.problems[0].fix
    assert any(p.file == str(part) for p in validate_dataset(folder))


def test_a_renamed_part_is_refused(partial, tmp_path):
    folder = _copy(partial, tmp_path)
    part = _first_part(folder)
    renamed = part.with_name("part-000099.parquet")
    part.rename(renamed)
    with pytest.raises(DataError, match="name says press 99") as err:
        resume_campaign(folder, progress=False, report=False)
    assert err.value.file == str(renamed)
    assert [p.field for p in validate_dataset(folder) if p.file == str(renamed)] == ["press_id"]


def test_another_campaigns_part_is_refused(partial, tmp_path):
    other = tmp_path / "other"
    protocol = tmp_path / "other.toml"
    protocol.write_text(SMOKE.read_text().replace('name = "smoke"', 'name = "other"'))
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(SMOKE.parent / sub, tmp_path / sub)
    done = run_cli_child("none", "campaign", "run", str(protocol), "--dry-run", "--out", str(other), "--limit", "6")
    assert done.returncode == 0, done.stderr
    folder = _copy(partial, tmp_path / "x")
    foreign = sorted((other / "presses").glob("part-*.parquet"))
    ours = {p.name for p in (folder / "presses").glob("part-*.parquet")}
    dropped = next(p for p in foreign if p.name not in ours)
    shutil.copyfile(dropped, folder / "presses" / dropped.name)
    with pytest.raises(DataError, match="belongs to another campaign") as err:
        resume_campaign(folder, progress=False, report=False)
    assert err.value.file == str(folder / "presses" / dropped.name)


def test_deleting_the_input_hash_does_not_switch_the_check_off(partial, tmp_path):
    folder = _copy(partial, tmp_path)
    manifest = json.loads((folder / "manifest.json").read_text())
    del manifest["protocol"]["sha256"]
    (folder / "manifest.json").write_text(json.dumps(manifest))
    protocol = folder / "inputs" / "protocol.toml"
    protocol.write_text(protocol.read_text().replace("seed = 7", "seed = 8"))
    with pytest.raises(DataError, match="not the file this campaign started with") as err:
        resume_campaign(folder, progress=False, report=False)
    assert err.value.file == str(protocol)  # the presses' own metadata still holds the hash


def test_a_damaged_presses_parquet_is_named_by_validate_and_restored_by_finish(reference, tmp_path):
    folder = _copy(reference, tmp_path)
    flip_bit_in_column(folder / "presses.parquet", "dR_ohm_1_2")
    problems = validate_dataset(folder)
    assert problems and all(p.file == str(folder / "presses.parquet") for p in problems)
    assert f"neatskin campaign finish {folder}" in problems[0].fix
    assert main(["dataset", "validate", str(folder)]) == 1
    finish_campaign(folder, report=False, progress=False)
    assert validate_dataset(folder) == []
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)


def test_a_string_rig_in_the_manifest_is_a_data_error(partial, tmp_path):
    folder = _copy(partial, tmp_path)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["rig"] = "dry-run"
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataError) as err:
        resume_campaign(folder, progress=False, report=False)
    assert err.value.field == "rig" and err.value.file == str(folder / "manifest.json")


def test_resume_of_the_untouched_partial_campaign_completes(partial, reference, tmp_path):
    """The control for the cases above: the same copy, untouched, resumes to the uninterrupted rows."""
    folder = _copy(partial, tmp_path)
    result = resume_campaign(folder, progress=False, report=False)
    assert (result.completed, result.written_now) == (12, 8)
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)

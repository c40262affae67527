"""Hostile press files: +-inf and 1e308 in a resistance column, a press off the skin with no --layout, an exact
duplicated row; validation names each, and merge, split, export and skin fit refuse what validation refuses."""

import shutil

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.validate import validate_dataset
from neatskin.datasets.writer import CampaignWriter
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_PATH = PROTOCOLS / "skins" / "paper.toml"


def make_campaign(folder, layout, campaign="edge", seed=9):
    from neatskin.datasets.writer import file_sha256

    ref = {"path": str(LAYOUT_PATH), "sha256": file_sha256(LAYOUT_PATH)}
    rows = synthetic_rows(layout, 5, 3, seed=seed, campaign=campaign)
    create_manifest(
        folder, fsync=False, campaign=campaign, seed=seed, layout=ref, counts={"planned": 15, "completed": 15}
    )
    with CampaignWriter(folder, layout.pairs, {"seed": seed, "layout": ref}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    update_manifest(folder, fsync=False, status="complete")
    return folder


def set_value(path, column, row, value):
    """Write `value` into one cell of a press file, keeping its metadata (as a hand edit would)."""
    table = pq.read_table(path)
    values = table.column(column).to_numpy().copy()
    values[row] = value
    k = table.column_names.index(column)
    edited = table.set_column(k, table.schema.field(k), pa.array(values))
    pq.write_table(edited.replace_schema_metadata(table.schema.metadata), path)


@pytest.mark.parametrize("value", [np.inf, -np.inf, 1e308])
def test_validate_a_lone_file_with_inf_or_1e308_exits_non_zero(paper_layout, tmp_path, capsys, value):
    folder = make_campaign(tmp_path / "c", paper_layout)
    lone = tmp_path / "lone.parquet"
    shutil.copy(folder / "presses.parquet", lone)
    set_value(lone, "R_ohm_1_2", 3, value)
    (problem,) = validate_dataset(lone)
    assert problem.field == "R_ohm_1_2" and problem.file == str(lone)
    assert ("infinite" if np.isinf(value) else "outside the plausible range 0..1e+09 ohm") in problem.message
    assert f"{value:g}" in problem.message and "press ids 3" in problem.message
    assert main(["dataset", "validate", str(lone)]) == 1
    assert "R_ohm_1_2" in capsys.readouterr().err


def test_inf_of_a_pair_cut_off_is_a_measurement_when_its_flag_says_so(paper_layout, tmp_path):
    folder = make_campaign(tmp_path / "c", paper_layout)
    path = folder / "presses.parquet"
    set_value(path, "R_ohm_1_2", 2, np.inf)
    set_value(path, "dR_ohm_1_2", 2, np.inf)
    table = pq.read_table(path)
    flags = table.column("flags").to_pylist()
    flags[2] = ["open_circuit:1-2"]
    k = table.column_names.index("flags")
    table = table.set_column(k, table.schema.field(k), pa.array(flags, pa.list_(pa.string())))
    pq.write_table(table, path)
    found = validate_dataset(folder, allow_flagged=True, notes=[])
    assert [p for p in found if p.field != "files_sha256"] == []
    set_value(path, "R_ohm_1_3", 2, np.inf)  # the flag names another pair: this one is not excused
    assert [p.field for p in validate_dataset(folder, allow_flagged=True) if p.field != "files_sha256"] == ["R_ohm_1_3"]


def test_a_press_off_the_skin_is_found_from_the_layout_the_metadata_names(paper_layout, tmp_path):
    folder = make_campaign(tmp_path / "c", paper_layout)
    lone = tmp_path / "lone.parquet"
    shutil.copy(folder / "presses.parquet", lone)
    set_value(lone, "x_mm", 4, 80.0)
    table = pq.read_table(lone)
    same_position = pc.equal(table.column("position_id"), table.column("position_id")[4])
    xs = pc.if_else(same_position, 80.0, table.column("x_mm"))  # the whole position moved: one problem only
    table = table.set_column(table.column_names.index("x_mm"), "x_mm", xs)
    pq.write_table(table, lone)
    (problem,) = validate_dataset(lone)
    assert problem.field == "x_mm, y_mm" and "outside the layout" in problem.message and "x 0..30 mm" in problem.message


def test_a_layout_the_metadata_names_but_that_is_gone_is_said_not_skipped(paper_layout, tmp_path, capsys):
    folder = tmp_path / "c"
    local = tmp_path / "src" / "skin.toml"
    local.parent.mkdir()
    shutil.copy(LAYOUT_PATH, local)
    from neatskin.datasets.writer import file_sha256

    ref = {"path": "skin.toml", "sha256": file_sha256(local)}
    rows = synthetic_rows(paper_layout, 2, 1, seed=3, campaign="gone")
    folder.mkdir()
    with CampaignWriter(folder, paper_layout.pairs, {"seed": 3, "layout": ref}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    lone = tmp_path / "elsewhere" / "deep" / "lone.parquet"
    lone.parent.mkdir(parents=True)
    shutil.copy(folder / "presses.parquet", lone)
    notes: list[str] = []
    assert validate_dataset(lone, notes=notes) == [] and "bounds were not checked" in notes[0]
    assert main(["dataset", "validate", str(lone)]) == 0
    assert "note: the bounds were not checked" in capsys.readouterr().err
    shutil.copy(local, lone.parent / "skin.toml")  # beside the file, with the recorded sha256: used
    notes = []
    assert validate_dataset(lone, notes=notes) == [] and notes == []


def test_an_exact_duplicated_row_is_a_problem(paper_layout, tmp_path):
    folder = make_campaign(tmp_path / "c", paper_layout)
    lone = tmp_path / "lone.parquet"
    table = pq.read_table(folder / "presses.parquet")
    pq.write_table(pa.concat_tables([table, table.slice(6, 1)]), lone)
    (problem,) = validate_dataset(lone)
    assert problem.field == "press_id" and "1 exact duplicate row(s) (press ids 6)" in problem.message

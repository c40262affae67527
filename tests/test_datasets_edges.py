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


def make_campaign(folder, layout, campaign="edge", seed=9, finalize=True):
    """A 5-position x 3-press synthetic campaign; finalize=False leaves it interrupted (parts only)."""
    from neatskin.datasets.writer import file_sha256

    ref = {"path": str(LAYOUT_PATH), "sha256": file_sha256(LAYOUT_PATH)}
    rows = synthetic_rows(layout, 5, 3, seed=seed, campaign=campaign)
    create_manifest(
        folder, fsync=False, campaign=campaign, seed=seed, layout=ref, counts={"planned": 15, "completed": 15}
    )
    with CampaignWriter(folder, layout.pairs, {"seed": seed, "layout": ref}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        if finalize:
            writer.finalize()
    update_manifest(folder, fsync=False, status="complete" if finalize else "interrupted")
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
    assert ("non-finite" if np.isinf(value) else "outside the plausible range 0..1e+09 ohm") in problem.message
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


def _no_traceback(err: str) -> None:
    assert "Traceback" not in err and err.count("neatskin: error:") == 1, err


def test_merge_refuses_a_folder_validate_refuses_unless_told_and_recorded(paper_layout, tmp_path, capsys):
    import json

    a = make_campaign(tmp_path / "a", paper_layout, "a", seed=1)
    b = make_campaign(tmp_path / "b", paper_layout, "b", seed=2)
    set_value(b / "presses.parquet", "R_ohm_1_2", 0, 1e308)
    set_value(b / "presses.parquet", "dR_ohm_1_3", 1, np.inf)
    assert main(["dataset", "merge", str(a), str(b), "-o", str(tmp_path / "m")]) == 5  # a data error
    err = capsys.readouterr().err
    _no_traceback(err)
    assert str(b) in err and "R_ohm_1_2" in err and "1e+308" in err and "--allow-invalid" in err
    assert not (tmp_path / "m").exists()
    assert main(["dataset", "merge", str(a), str(b), "-o", str(tmp_path / "m"), "--allow-invalid"]) == 0
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    assert manifest["allow_invalid"] is True
    (recorded,) = manifest["invalid_sources"].values()
    assert any("R_ohm_1_2" in p for p in recorded) and any("dR_ohm_1_3" in p for p in recorded)
    clean = json.loads(json.dumps(manifest["sources"]))
    assert len(clean) == 2


def test_merge_with_flags_typed_list_of_null_first_gives_string_flags(paper_layout, tmp_path, capsys):
    a = make_campaign(tmp_path / "a", paper_layout, "a", seed=1)
    b = make_campaign(tmp_path / "b", paper_layout, "b", seed=2)
    table = pq.read_table(a / "presses.parquet")
    k = table.column_names.index("flags")
    nulls = pa.array([[]] * table.num_rows, pa.list_(pa.null()))  # what pandas writes for all-empty flags
    pq.write_table(table.set_column(k, pa.field("flags", nulls.type), nulls), a / "presses.parquet")
    assert main(["dataset", "merge", str(a), str(b), "-o", str(tmp_path / "m")]) == 0, capsys.readouterr().err
    merged = pq.read_table(tmp_path / "m" / "presses.parquet")
    assert merged.schema.field("flags").type == pa.list_(pa.string()) and merged.num_rows == 30


@pytest.mark.parametrize("command", ["split", "export"])
def test_split_and_export_refuse_non_finite_data_with_one_clear_error(paper_layout, tmp_path, capsys, command):
    folder = make_campaign(tmp_path / "c", paper_layout)
    set_value(folder / "presses.parquet", "dR_ohm_2_6", 5, -np.inf)
    out = tmp_path / ("out" if command == "split" else "out.parquet")
    assert main(["dataset", command, str(folder), "-o", str(out)]) == 5  # a data error
    err = capsys.readouterr().err
    _no_traceback(err)
    assert f"{command} refused" in err and "[dR_ohm_2_6]" in err and "press ids 5" in err
    assert not out.exists()


def test_skin_fit_with_nan_in_x_mm_ends_in_one_clear_error(paper_layout, tmp_path, capsys):
    folder = make_campaign(tmp_path / "c", paper_layout)
    (folder / "inputs").mkdir(exist_ok=True)
    shutil.copy(LAYOUT_PATH, folder / "inputs" / "layout.toml")
    set_value(folder / "presses.parquet", "x_mm", 2, np.nan)
    assert main(["skin", "fit", str(folder)]) == 5  # a data error
    err = capsys.readouterr().err
    _no_traceback(err)
    assert "[x_mm]" in err and "NaN or infinite in x_mm (press ids [2])" in err


def _set_flags(path, flags_by_row):
    table = pq.read_table(path)
    flags = table.column("flags").to_pylist()
    for row, flags_of_row in flags_by_row.items():
        flags[row] = flags_of_row
    k = table.column_names.index("flags")
    table = table.set_column(k, table.schema.field(k), pa.array(flags, pa.list_(pa.string())))
    pq.write_table(table, path)


def test_a_press_that_cut_pairs_is_valid_without_allow_flagged_and_any_other_flag_is_not(paper_layout, tmp_path):
    """A channel pinched shut (the FE skin at the paper's depth cuts a pair on a third of the presses) leaves
    open_circuit/clipped flags: a measurement of the skin, which validate accepts; a rig fault still needs
    --allow-flagged."""
    folder = make_campaign(tmp_path / "c", paper_layout)
    path = folder / "presses.parquet"
    for column in ("R_ohm_1_2", "dR_ohm_1_2"):
        set_value(path, column, 2, np.inf)
    _set_flags(path, {2: ["open_circuit:1-2", "clipped:1-2"]})
    assert [p for p in validate_dataset(folder) if p.field != "files_sha256"] == []
    _set_flags(path, {2: ["open_circuit:1-2", "clipped:1-2"], 4: ["fsr_missed"]})
    (flagged,) = [p for p in validate_dataset(folder) if p.field != "files_sha256"]
    assert flagged.field == "flags" and "1 flagged press(es)" in flagged.message and "press ids 4" in flagged.message

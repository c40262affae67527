"""Validation finds each kind of problem once, naming the file, the column and the fix."""

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS

from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.validate import check_dataset, validate_dataset
from neatskin.datasets.writer import CampaignWriter
from neatskin.errors import DataError
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_REF = {"path": str(PROTOCOLS / "skins" / "paper.toml"), "name": "neatskin-paper"}


def make_campaign(folder, layout, rows=None, finalize=True):
    rows = rows if rows is not None else synthetic_rows(layout, 5, 3, seed=9, campaign="val")
    create_manifest(
        folder, fsync=False, campaign="val", seed=9, layout=LAYOUT_REF, counts={"planned": 15, "completed": len(rows)}
    )
    with CampaignWriter(folder, layout.pairs, {"seed": 9, "layout": LAYOUT_REF}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        if finalize:
            writer.finalize()
    update_manifest(folder, fsync=False, status="complete")
    return rows


def rewrite(folder, edit):
    path = folder / "presses.parquet"
    table = pq.read_table(path)
    pq.write_table(edit(table).replace_schema_metadata(table.schema.metadata), path)


def only(problems):
    assert len(problems) == 1, "\n".join(map(str, problems))
    return problems[0]


def test_clean_campaign_has_no_problems(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)
    assert validate_dataset(tmp_path) == []
    check_dataset(tmp_path)


def test_clean_unfinalized_parts_have_no_problems(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout, finalize=False)
    assert validate_dataset(tmp_path) == []


def test_missing_pair_column(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)
    rewrite(tmp_path, lambda t: t.drop_columns(["dR_ohm_3_4"]))
    p = only(validate_dataset(tmp_path))
    assert p.field == "dR_ohm_3_4" and p.file.endswith("presses.parquet") and "missing" in p.message and p.fix


def test_wrong_column_type(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)
    rewrite(
        tmp_path,
        lambda t: t.set_column(t.schema.get_field_index("repeat"), "repeat", pc.cast(t.column("repeat"), pa.float64())),
    )
    p = only(validate_dataset(tmp_path))
    assert p.field == "repeat" and "double" in p.message and "int32" in p.message


def test_nan_value(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")
    rows[7]["dR_ohm"] = rows[7]["dR_ohm"].copy()
    rows[7]["dR_ohm"][0] = np.nan
    make_campaign(tmp_path, paper_layout, rows)
    p = only(validate_dataset(tmp_path))
    assert p.field == "dR_ohm_1_2" and "press ids 7" in p.message and "1 NaN" in p.message


def test_duplicate_press_id(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)

    def duplicate(t):
        extra = t.slice(3, 1)
        k = extra.schema.get_field_index("dR_ohm_1_2")
        extra = extra.set_column(k, extra.schema.field(k), pa.array([123.0]))
        return pa.concat_tables([t, extra])

    rewrite(tmp_path, duplicate)
    update_manifest(tmp_path, fsync=False)
    p = only(validate_dataset(tmp_path))
    assert p.field == "press_id" and "3" in p.message


def test_identical_copy_in_part_and_consolidated_is_not_a_duplicate(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)
    one = pq.read_table(tmp_path / "presses.parquet").slice(2, 1)
    pq.write_table(one, tmp_path / "presses" / "part-000002.parquet")  # a kill during finalize's cleanup
    assert validate_dataset(tmp_path) == []


def test_position_outside_layout(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")
    for row in rows:
        if row["position_id"] == 2:
            row["x_mm"] = 41.0
    make_campaign(tmp_path, paper_layout, rows)
    p = only(validate_dataset(tmp_path))
    assert p.field == "x_mm, y_mm" and "3 press(es)" in p.message and "press ids 6, 7, 8" in p.message


def test_flagged_rows(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")
    rows[4]["flags"] = ["fsr_missed"]
    rows[9]["flags"] = ["fsr_missed", "clipped"]
    make_campaign(tmp_path, paper_layout, rows)
    p = only(validate_dataset(tmp_path))
    assert p.field == "flags" and "2 flagged" in p.message and "fsr_missed: 2" in p.message
    assert validate_dataset(tmp_path, allow_flagged=True) == []


def test_manifest_count_and_seed_mismatch(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout)
    update_manifest(tmp_path, fsync=False, counts={"completed": 14})
    p = only(validate_dataset(tmp_path))
    assert p.field == "counts.completed" and p.file.endswith("manifest.json") and "14" in p.message
    update_manifest(tmp_path, fsync=False, counts={"completed": 15}, seed=10)
    p = only(validate_dataset(tmp_path))
    assert p.field == "seed"


def test_incomplete_campaign_marked_complete(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")[:12]
    make_campaign(tmp_path, paper_layout, rows)
    p = only(validate_dataset(tmp_path))
    assert p.field == "counts.planned" and "12 of 15" in p.message


def test_manifest_layout_missing_and_manifest_absent(paper_layout, tmp_path):
    make_campaign(tmp_path / "a", paper_layout)
    update_manifest(tmp_path / "a", fsync=False, layout={"path": "nowhere/skin.toml", "name": "neatskin-paper"})
    p = only(validate_dataset(tmp_path / "a"))
    assert p.field == "layout.path" and "cannot be loaded" in p.message
    make_campaign(tmp_path / "b", paper_layout)
    (tmp_path / "b" / "manifest.json").unlink()
    p = only(validate_dataset(tmp_path / "b"))
    assert p.file.endswith("manifest.json") and "no manifest" in p.message


def test_several_problems_at_once_and_check_raises(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")
    rows[1]["flags"] = ["clipped"]
    rows[2]["R_ohm"] = np.full(28, np.nan)
    make_campaign(tmp_path, paper_layout, rows)
    problems = validate_dataset(tmp_path)
    assert len(problems) == 29  # 28 R columns with a NaN, 1 flagged press
    with pytest.raises(DataError) as err:
        check_dataset(tmp_path)
    assert len(err.value.problems) == 29 and "fix:" in str(err.value)


def test_orphan_and_misplaced_waveform_parts(paper_layout, tmp_path):
    rows = make_campaign(tmp_path, paper_layout, finalize=False)
    with CampaignWriter(tmp_path, paper_layout.pairs, {"seed": 9, "layout": LAYOUT_REF}, fsync=False) as writer:
        writer.finalize()
    wave = pa.table({"press_id": [3], "sample": [0], "voltage_v": [0.5]})
    (tmp_path / "waveforms" / "position_id=1").mkdir(parents=True)
    pq.write_table(wave, tmp_path / "waveforms" / "position_id=1" / "part-000003.parquet")  # press 3: position 1
    assert rows[3]["position_id"] == 1 and validate_dataset(tmp_path) == []
    (tmp_path / "waveforms" / "position_id=4").mkdir()
    pq.write_table(wave, tmp_path / "waveforms" / "position_id=4" / "part-000004.parquet")  # press 4 is at 1
    pq.write_table(wave, tmp_path / "waveforms" / "position_id=4" / "part-000099.parquet")  # no press 99
    problems = validate_dataset(tmp_path)
    assert sorted(p.field for p in problems) == ["position_id", "press_id"]
    assert all("1 waveform part(s)" in p.message for p in problems)


def _merge_parts(folder, ids, name_id):
    """Replace the parts of `ids` by one part named for press `name_id` holding their rows in that order."""
    parts = folder / "presses"
    tables = [pq.read_table(parts / f"part-{i:06d}.parquet") for i in ids]
    for i in ids:
        (parts / f"part-{i:06d}.parquet").unlink()
    pq.write_table(pa.concat_tables(tables), parts / f"part-{name_id:06d}.parquet")


def test_part_of_several_rows_with_increasing_ids_is_valid(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout, finalize=False)
    _merge_parts(tmp_path, [5, 6, 7], 5)
    _merge_parts(tmp_path, [10, 12], 10)  # a gap is fine: ids need only increase
    assert sorted(p.name for p in (tmp_path / "presses").iterdir())[4:7] == [
        "part-000004.parquet",
        "part-000005.parquet",
        "part-000008.parquet",
    ]
    assert validate_dataset(tmp_path) == []


@pytest.mark.parametrize(
    ("ids", "name_id", "shown"),
    [
        ([6, 7], 5, "[6, 7]"),  # the name says 5, the first row is 6
        ([5, 7, 6], 5, "[5, 7, 6]"),  # not increasing
        ([7, 7], 7, "[7, 7]"),  # a repeated id (the same row twice)
    ],
)
def test_part_whose_ids_do_not_start_at_its_name_or_do_not_increase(paper_layout, tmp_path, ids, name_id, shown):
    make_campaign(tmp_path, paper_layout, finalize=False)
    _merge_parts(tmp_path, sorted(set(ids)), 99)
    table = pq.read_table(tmp_path / "presses" / "part-000099.parquet")
    order = [sorted(set(ids)).index(i) for i in ids]
    (tmp_path / "presses" / "part-000099.parquet").unlink()
    pq.write_table(table.take(pa.array(order)), tmp_path / "presses" / f"part-{name_id:06d}.parquet")
    problems = [p for p in validate_dataset(tmp_path) if "the part's name says" in p.message]
    p = only(problems)
    assert p.message == f"the part's name says press {name_id} but it holds press id(s) {shown}"
    assert p.field == "press_id" and p.file.endswith(f"part-{name_id:06d}.parquet") and "resume" in p.fix


def test_problems_found_across_row_groups_as_in_one_piece(paper_layout, tmp_path):
    """Validation reads row group by row group: NaNs, flags and duplicates in different groups of one file
    are counted together, and a press in a part that is the same row as in presses.parquet is no duplicate."""
    rows = synthetic_rows(paper_layout, 5, 3, seed=9, campaign="val")
    for k in (2, 13):
        rows[k]["dR_ohm"] = rows[k]["dR_ohm"].copy()
        rows[k]["dR_ohm"][27] = np.nan
    rows[6]["flags"] = ["fsr_missed"]
    rows[11]["flags"] = ["fsr_missed"]
    make_campaign(tmp_path, paper_layout, rows)
    path = tmp_path / "presses.parquet"
    table = pq.read_table(path)
    copy = table.slice(9, 1)  # press 9 again, one value changed: a duplicate with a different row
    k = copy.schema.get_field_index("x_mm")
    changed = copy.set_column(k, copy.schema.field(k), pa.array([copy.column("x_mm")[0].as_py() + 0.5]))
    pq.write_table(pa.concat_tables([table, changed]), path, row_group_size=4)
    assert pq.ParquetFile(path).metadata.num_row_groups == 4
    pq.write_table(table.slice(5, 1), tmp_path / "presses" / "part-000005.parquet")  # the same row: fine
    problems = {p.field: p for p in validate_dataset(tmp_path)}
    assert problems["dR_ohm_7_8"].message == "2 NaN/null value(s) in 'dR_ohm_7_8' (press ids 2, 13)"
    assert problems["flags"].message.startswith("2 flagged press(es) (fsr_missed: 2; press ids 6, 11)")
    assert problems["press_id"].message == "duplicate press id(s) with different rows: 9"
    assert problems["position_id"].message == "position id(s) 3 have presses at different x/y"
    assert set(problems) == {"dR_ohm_7_8", "flags", "press_id", "position_id"}


def test_file_damaged_in_a_later_row_group_is_unreadable_as_a_whole(paper_layout, tmp_path):
    make_campaign(tmp_path, paper_layout, finalize=False)
    parts = tmp_path / "presses"
    big = pa.concat_tables([pq.read_table(parts / f"part-{i:06d}.parquet") for i in range(3, 15)])
    for i in range(4, 15):
        (parts / f"part-{i:06d}.parquet").unlink()
    pq.write_table(big, parts / "part-000003.parquet", row_group_size=4, write_page_checksum=True)
    data = bytearray((parts / "part-000003.parquet").read_bytes())
    handle = pq.ParquetFile(parts / "part-000003.parquet")
    last = handle.metadata.row_group(2).column(40)  # a dR column of the last group
    offset = last.data_page_offset + last.total_compressed_size - 20
    data[offset] ^= 0xFF
    (parts / "part-000003.parquet").write_bytes(bytes(data))
    problems = validate_dataset(tmp_path)
    unreadable = [p for p in problems if p.message.startswith("unreadable parquet file")]
    assert len(unreadable) == 1 and unreadable[0].file.endswith("part-000003.parquet")
    # nothing of the damaged part counts: 3 presses (0, 1, 2) remain against the manifest's 15
    assert any(p.field == "counts.completed" and "holds 3 presses" in p.message for p in problems)

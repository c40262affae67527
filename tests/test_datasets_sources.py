"""Merged rows name their source run, keys stay unique per row, and a merge of a merge keeps the names."""

from __future__ import annotations

import pyarrow.parquet as pq
from test_datasets_curate import campaign

from neatskin.datasets.curate import merge
from neatskin.datasets.merging import source_run_names
from neatskin.datasets.reader import read_metadata, read_presses
from neatskin.datasets.validate import validate_dataset


def test_merged_rows_name_their_two_source_runs_and_press_ids_are_unique(paper_layout, tmp_path):
    # both campaigns are named "c": the campaign column cannot tell their rows apart; source_run can
    a = campaign(tmp_path / "run-0900", paper_layout, 6, 3, seed=1, name="c")
    b = campaign(tmp_path / "run-1400", paper_layout, 4, 2, seed=2, name="c")
    out = merge([tmp_path / "run-0900", tmp_path / "run-1400"], tmp_path / "m")
    df = read_presses(out)
    assert df["source_run"].tolist() == ["run-0900"] * len(a) + ["run-1400"] * len(b)
    assert df["campaign"].nunique() == 1 and df["repeat"].duplicated().any()  # the old keys could not
    assert df["press_id"].is_unique and len(df) == 26
    assert df[["source_run", "press_id"]].drop_duplicates().shape[0] == 26
    names = pq.read_schema(out / "presses.parquet").names
    assert names[:3] == ["campaign", "source_run", "press_id"]
    assert read_metadata(out)["source_runs"] == ["run-0900", "run-1400"]
    assert validate_dataset(out) == []  # the validator knows the column


def test_a_merge_of_a_merge_keeps_each_rows_original_run(paper_layout, tmp_path):
    campaign(tmp_path / "a", paper_layout, 3, 2, seed=1, name="a")
    campaign(tmp_path / "b", paper_layout, 3, 2, seed=2, name="b")
    campaign(tmp_path / "c", paper_layout, 2, 2, seed=3, name="c")
    ab = merge([tmp_path / "a", tmp_path / "b"], tmp_path / "ab")
    abc = merge([ab, tmp_path / "c"], tmp_path / "abc")
    df = read_presses(abc)
    assert df["source_run"].tolist() == ["a"] * 6 + ["b"] * 6 + ["c"] * 4
    assert df["press_id"].is_unique


def test_run_names_are_folder_names_and_a_shared_name_is_numbered(tmp_path):
    (tmp_path / "x" / "run").mkdir(parents=True)
    (tmp_path / "y" / "run").mkdir(parents=True)
    (tmp_path / "z").mkdir()
    assert source_run_names([tmp_path / "x" / "run", tmp_path / "y" / "run", tmp_path / "z"]) == [
        "run#1",
        "run#2",
        "z",
    ]


def test_every_waveform_part_carries_the_campaigns_metadata_and_its_press(paper_layout, tmp_path):
    import numpy as np

    from neatskin.datasets.schema import decode_metadata
    from neatskin.datasets.writer import CampaignWriter
    from neatskin.skin.synthetic import synthetic_rows

    rows = synthetic_rows(paper_layout, 2, 2, seed=5)
    meta = {"seed": 7, "campaign": "wf", "layout": {"path": "inputs/layout.toml"}}
    with CampaignWriter(tmp_path, paper_layout.pairs, meta, fsync=False) as writer:
        for row in rows:
            writer.write_press(row, {"voltage_v": np.arange(8.0), "current_a": np.ones(8)})
        writer.finalize()
    parts = sorted((tmp_path / "waveforms").rglob("part-*.parquet"))
    assert len(parts) == len(rows)
    press_meta = decode_metadata(pq.read_schema(tmp_path / "presses.parquet").metadata)
    for part, row in zip(sorted(parts, key=lambda p: int(p.stem.split("-")[1])), rows):
        got = decode_metadata(pq.read_schema(part).metadata)
        assert got["press_id"] == row["press_id"] and got["position_id"] == row["position_id"]
        for key in ("seed", "campaign", "layout", "pairs", "schema_version", "software_version"):
            assert got[key] == press_meta[key], key

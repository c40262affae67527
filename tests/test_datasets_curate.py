"""Curation: describe, merge (refusing mixed skins), split by position, export, and the PNG plots."""

import json
import struct

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.datasets.curate import (
    SENSITIVITY_MEASURE,
    describe,
    export,
    merge,
    most_sensitive_pairs,
    split,
    split_positions,
)
from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.plots import plot_press_map, plot_sensitivity_map, sensitivity_by_position
from neatskin.datasets.reader import read_metadata, read_presses
from neatskin.datasets.validate import validate_dataset
from neatskin.datasets.writer import CampaignWriter
from neatskin.errors import DataError
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_REF = {"path": str(PROTOCOLS / "skins" / "paper.toml"), "name": "neatskin-paper"}


def campaign(
    folder, layout, n_positions=6, repeats=3, seed=0, name="c", layout_ref=LAYOUT_REF, wiring="paper-wiring", flagged=()
):
    rows = synthetic_rows(layout, n_positions, repeats, seed=seed, campaign=name)
    for k in flagged:
        rows[k]["flags"] = ["fsr_missed"]
    n = len(rows)
    create_manifest(
        folder,
        fsync=False,
        campaign=name,
        seed=seed,
        layout=layout_ref,
        wiring={"name": wiring},
        counts={"planned": n, "completed": n},
    )
    with CampaignWriter(folder, layout.pairs, {"seed": seed, "layout": layout_ref}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    update_manifest(folder, fsync=False, status="complete")
    return rows


def png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_describe(paper_layout, tmp_path):
    campaign(tmp_path, paper_layout, 5, 4, flagged=(2, 3))
    info = describe(tmp_path)
    assert (info["presses"], info["positions"], info["pairs"]) == (20, 5, 28)
    assert info["repeats_per_position"] == {"min": 4, "max": 4}
    assert info["flagged_presses"] == 2 and info["flags"] == {"fsr_missed": 2}
    assert info["seed"] == 0 and info["status"] == "complete" and info["depth_mm"] == [3.5]
    assert info["files"] == {"consolidated": True, "press_parts": 0, "waveform_parts": 0}


def test_describe_ranks_pairs_on_the_presses_that_did_not_cut_them(paper_layout, tmp_path):
    """A cut pair's dR is +inf on that press: ranked over all presses, every pair ever cut ranked inf and tied, and a
    paper dry run said ["1-2", "1-3", "1-4"], the first three columns. The ranking is on the finite values."""
    pairs = [f"{p.i}-{p.j}" for p in paper_layout.pairs]
    rows = synthetic_rows(paper_layout, 4, 3, seed=0)
    cut, strong, never = pairs.index("1-2"), pairs.index("2-6"), pairs.index("3-7")
    for k, row in enumerate(rows):
        row["dR_ohm"] = np.array(row["dR_ohm"], dtype=float)
        row["R_ohm"] = np.array(row["R_ohm"], dtype=float)
        row["dR_ohm"][strong] = 50_000.0 + k  # clearly the most sensitive pair: mean |dR| 50,005.5 ohm
        row["R_ohm"][never], row["dR_ohm"][never] = np.inf, np.inf  # cut on every press: no value, no rank
        row["flags"] = ["open_circuit:3-7"]
    for k in (0, 5):
        rows[k]["R_ohm"][cut], rows[k]["dR_ohm"][cut] = np.inf, np.inf
        rows[k]["flags"] = ["open_circuit:1-2", "open_circuit:3-7"]
    rows[7]["dR_ohm"][pairs.index("1-3")] = -np.inf  # a baseline that was cut, a press that was not
    dr = pd.DataFrame([r["dR_ohm"] for r in rows], columns=[f"dR_ohm_{p.replace('-', '_')}" for p in pairs])
    finite = dr.where(np.isfinite(dr))
    expected = finite.abs().mean().dropna().sort_values(ascending=False)
    ranked = most_sensitive_pairs(dr)
    assert ranked["by"] == SENSITIVITY_MEASURE and "did not cut" in ranked["by"]
    assert list(ranked["pairs"]) == [c.removeprefix("dR_ohm_").replace("_", "-") for c in expected.index[:3]]
    assert list(ranked["pairs"])[0] == "2-6" and ranked["pairs"]["2-6"] == pytest.approx(50_005.5)
    assert "3-7" not in most_sensitive_pairs(dr, count=28)["pairs"] and len(most_sensitive_pairs(dr, 28)["pairs"]) == 27
    # the cut pair's rank comes from its 10 finite presses, not its two inf ones
    mean_12 = float(np.mean(np.abs(np.delete(dr["dR_ohm_1_2"].to_numpy(), [0, 5]))))
    assert most_sensitive_pairs(dr, count=28)["pairs"]["1-2"] == pytest.approx(mean_12, abs=1e-3)

    create_manifest(tmp_path, fsync=False, campaign="c", seed=0, layout=LAYOUT_REF, counts={"planned": 12})
    with CampaignWriter(tmp_path, paper_layout.pairs, {"seed": 0}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    assert describe(tmp_path)["most_sensitive_pairs"] == ranked  # what `dataset info` prints


def test_merge_rekeys_and_keeps_provenance(paper_layout, tmp_path):
    a = campaign(tmp_path / "a", paper_layout, 6, 3, seed=1, name="a")
    b = campaign(tmp_path / "b", paper_layout, 4, 2, seed=2, name="b")
    out = merge([tmp_path / "a", tmp_path / "b"], tmp_path / "m")
    df = read_presses(out)
    assert df["press_id"].tolist() == list(range(26))
    assert df["position_id"].tolist() == [r["position_id"] for r in a] + [6 + r["position_id"] for r in b]
    assert df["campaign"].tolist() == ["a"] * 18 + ["b"] * 8
    np.testing.assert_array_equal(df.loc[18:, "dR_ohm_2_6"], [r["dR_ohm"][10] for r in b])
    meta = read_metadata(out)
    assert [(s["press_id_offset"], s["presses"]) for s in meta["merged_from"]] == [(0, 18), (18, 8)]
    assert [s["position_ids"] for s in meta["merged_from"]] == [
        {str(k): k for k in range(6)},
        {str(k): 6 + k for k in range(4)},
    ]
    assert meta["merged_from"][1]["manifest"]["campaign"] == "b"
    assert validate_dataset(out) == []


def test_merge_streams_sources_into_fixed_row_groups(paper_layout, tmp_path, monkeypatch):
    """Merge writes source after source in row groups of MERGE_ROW_GROUP rows, never all rows at once: the
    rows and counts are those of the sources, re-keyed, whatever the group size; a source still in parts
    (interrupted, merged with --allow-incomplete) streams like a finished one."""
    import neatskin.datasets.merging as merging

    monkeypatch.setattr(merging, "MERGE_ROW_GROUP", 7)
    a = campaign(tmp_path / "a", paper_layout, 6, 3, seed=1, name="a", flagged=(4,))
    rows_b = synthetic_rows(paper_layout, 4, 2, seed=2, campaign="b")
    create_manifest(
        tmp_path / "b", fsync=False, campaign="b", seed=2, layout=LAYOUT_REF, wiring={"name": "paper-wiring"}
    )
    with CampaignWriter(tmp_path / "b", paper_layout.pairs, {"seed": 2, "layout": LAYOUT_REF}, fsync=False) as writer:
        for row in rows_b[:5]:
            writer.write_press(row)  # interrupted after 5 presses: parts only, no presses.parquet
    update_manifest(tmp_path / "b", fsync=False, status="interrupted")
    c = campaign(tmp_path / "c", paper_layout, 2, 2, seed=3, name="c")
    out = merge([tmp_path / "a", tmp_path / "b", tmp_path / "c"], tmp_path / "m", allow_incomplete=True)
    handle = pq.ParquetFile(out / "presses.parquet")
    sizes = [handle.metadata.row_group(k).num_rows for k in range(handle.metadata.num_row_groups)]
    assert sizes == [7, 7, 7, 6]  # 18 + 5 + 4 = 27 rows
    df = read_presses(out)
    assert df["press_id"].tolist() == list(range(18)) + [18 + k for k in range(5)] + [23 + k for k in range(4)]
    assert df["campaign"].tolist() == ["a"] * 18 + ["b"] * 5 + ["c"] * 4
    np.testing.assert_array_equal(df.loc[23:, "dR_ohm_1_2"], [r["dR_ohm"][0] for r in c])
    np.testing.assert_array_equal(df.loc[:17, "x_mm"], [r["x_mm"] for r in a])
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["counts"] == {"planned": 27, "completed": 27, "flagged": 1}
    assert validate_dataset(out, allow_flagged=True) == []


def test_merge_leaves_out_presses_written_while_it_merges(paper_layout, tmp_path, monkeypatch):
    """A running campaign merged with --allow-incomplete may commit a press between merge's plan and its
    stream: that press is left out (its id would overlap the next source's), the counts stay consistent."""
    import neatskin.datasets.merging as merging

    campaign(tmp_path / "a", paper_layout, 3, 2, seed=1, name="a")
    rows_b = synthetic_rows(paper_layout, 3, 2, seed=2, campaign="b")
    create_manifest(
        tmp_path / "b", fsync=False, campaign="b", seed=2, layout=LAYOUT_REF, wiring={"name": "paper-wiring"}
    )
    with CampaignWriter(tmp_path / "b", paper_layout.pairs, {"seed": 2, "layout": LAYOUT_REF}, fsync=False) as writer:
        for row in rows_b[:4]:
            writer.write_press(row)
    update_manifest(tmp_path / "b", fsync=False, status="interrupted")
    campaign(tmp_path / "c", paper_layout, 2, 2, seed=3, name="c")
    plan = merging._plan_source

    def plan_then_press(folder):
        planned = plan(folder)
        if folder.name == "b":  # the campaign goes on: press 4 commits after b was planned
            with CampaignWriter(folder, paper_layout.pairs, {"seed": 2, "layout": LAYOUT_REF}, fsync=False) as w:
                w.write_press(rows_b[4])
        return planned

    monkeypatch.setattr(merging, "_plan_source", plan_then_press)
    out = merge([tmp_path / "a", tmp_path / "b", tmp_path / "c"], tmp_path / "m", allow_incomplete=True)
    df = read_presses(out)
    assert df["press_id"].tolist() == list(range(14))
    assert df["campaign"].tolist() == ["a"] * 6 + ["b"] * 4 + ["c"] * 4
    assert json.loads((out / "manifest.json").read_text())["counts"]["completed"] == 14


def test_merge_refuses_mixed_layouts_and_wirings_unless_told(paper_layout, tmp_path):
    campaign(tmp_path / "a", paper_layout, seed=1)
    campaign(tmp_path / "b", paper_layout, seed=2, layout_ref={**LAYOUT_REF, "name": "finer-grid"})
    campaign(tmp_path / "c", paper_layout, seed=3, wiring="other-board")
    with pytest.raises(DataError) as err:
        merge([tmp_path / "a", tmp_path / "b"], tmp_path / "m1")
    assert err.value.field == "layout" and err.value.file.endswith("b") and "--allow-mixed" in str(err.value)
    with pytest.raises(DataError) as err:
        merge([tmp_path / "a", tmp_path / "c"], tmp_path / "m2")
    assert err.value.field == "wiring"
    assert not (tmp_path / "m1").exists() and not (tmp_path / "m2").exists()
    out = merge([tmp_path / "a", tmp_path / "b", tmp_path / "c"], tmp_path / "m3", allow_mixed=True)
    assert len(read_presses(out)) == 54


def test_merge_refuses_other_pairs_and_existing_output(paper_layout, tmp_path):
    campaign(tmp_path / "a", paper_layout)
    (tmp_path / "b").mkdir()
    table = pq.read_table(tmp_path / "a" / "presses.parquet")
    from neatskin.datasets.schema import decode_metadata, encode_metadata

    # a campaign measuring other pairs: its metadata says so (columns dropped under intact metadata are damage,
    # refused as missing columns: test_datasets_damaged.py)
    meta = decode_metadata(table.schema.metadata)
    meta["pairs"] = [p for p in meta["pairs"] if p != [7, 8]]
    other = table.drop_columns(["R_ohm_7_8", "dR_ohm_7_8"]).replace_schema_metadata(encode_metadata(meta))
    pq.write_table(other, tmp_path / "b" / "presses.parquet")
    with pytest.raises(DataError) as err:
        merge([tmp_path / "a", tmp_path / "b"], tmp_path / "m", allow_mixed=True)
    assert err.value.field == "pairs"
    with pytest.raises(DataError, match="not empty"):
        merge([tmp_path / "a", tmp_path / "a"], tmp_path / "a")


def test_split_is_by_position(paper_layout, tmp_path):
    campaign(tmp_path / "c", paper_layout, 20, 3, seed=4)
    parts = split(tmp_path / "c", tmp_path / "s", test_fraction=0.25, seed=7)
    train, test = read_presses(parts["train"]), read_presses(parts["test"])
    assert set(train["position_id"]).isdisjoint(test["position_id"])
    assert test["position_id"].nunique() == 5 and train["position_id"].nunique() == 15
    assert (test.groupby("position_id").size() == 3).all() and (train.groupby("position_id").size() == 3).all()
    together = pd.concat([train, test]).sort_values("press_id").reset_index(drop=True)
    pd.testing.assert_frame_equal(together, read_presses(tmp_path / "c"), check_like=False)
    again = split(tmp_path / "c", tmp_path / "s2", test_fraction=0.25, seed=7)
    assert read_presses(again["test"])["position_id"].tolist() == test["position_id"].tolist()
    assert validate_dataset(parts["train"]) == [] and validate_dataset(parts["test"]) == []
    manifest = json.loads((parts["test"] / "manifest.json").read_text())
    assert manifest["split"]["position_ids"] == sorted(set(test["position_id"]))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 40), min_size=2, max_size=300), st.floats(0.01, 0.99), st.integers(0, 2**32 - 1))
def test_split_positions_property(ids, fraction, seed):
    ids = np.array(ids)
    if np.unique(ids).size < 2:
        with pytest.raises(DataError):
            split_positions(ids, fraction, seed)
        return
    train, test = split_positions(ids, fraction, seed)
    assert set(train).isdisjoint(test) and set(train) | set(test) == set(ids)
    assert len(test) >= 1 and len(train) >= 1


def test_split_refuses_bad_fraction(paper_layout, tmp_path):
    campaign(tmp_path / "c", paper_layout)
    with pytest.raises(DataError) as err:
        split(tmp_path / "c", tmp_path / "s", test_fraction=1.0)
    assert err.value.field == "test_fraction"


def test_export_csv_and_parquet(paper_layout, tmp_path):
    rows = campaign(tmp_path / "c", paper_layout, 4, 2, flagged=(1,))
    csv = export(tmp_path / "c", tmp_path / "out.csv", "csv")
    back = pd.read_csv(csv)
    assert len(back) == 8 and back.columns[13] == "R_ohm_1_2"
    np.testing.assert_array_equal(back["dR_ohm_1_5"], [r["dR_ohm"][3] for r in rows])
    assert back["flags"].fillna("").tolist()[:2] == ["", "fsr_missed"]
    assert pd.to_datetime(back["started_at"])[1] == pd.Timestamp("2026-01-01T00:00:02", tz="UTC")
    assert json.loads((tmp_path / "out.csv.metadata.json").read_text())["seed"] == 0
    pq_out = export(tmp_path / "c", tmp_path / "clean.parquet", "parquet", drop_flagged=True)
    assert pd.read_parquet(pq_out)["press_id"].tolist() == [0, 2, 3, 4, 5, 6, 7]
    assert read_metadata(pq_out)["seed"] == 0
    with pytest.raises(DataError):
        export(tmp_path / "c", tmp_path / "clean.parquet", "parquet")
    with pytest.raises(DataError) as err:
        export(tmp_path / "c", tmp_path / "x.xlsx", "xlsx")
    assert err.value.field == "format"


def test_sensitivity_by_position_exact():
    df = pd.DataFrame(
        {
            "position_id": [0, 0, 1, 1, 2],
            "x_mm": [1.0, 1.0, 2.0, 2.0, 3.0],
            "y_mm": [0.0, 0.0, 5.0, 5.0, 9.0],
            "flags": [[], [], [], [], ["clipped"]],
            "dR_ohm_1_2": [10.0, 30.0, -4.0, -8.0, 999.0],
            "dR_ohm_1_3": [5.0, 5.0, -2.0, -2.0, 999.0],
        }
    )
    sens = sensitivity_by_position(df)
    assert sens["position_id"].tolist() == [0, 1]  # the flagged press is left out
    assert sens["z"].tolist() == [1.0, -0.1]  # max(20, 5) = 20 -> 1; max(-6, -2) = -2 -> -0.1
    assert sens["best_pair"].tolist() == ["1-2", "1-3"] and sens["presses"].tolist() == [2, 2]


def test_synthetic_map_is_high_on_periphery_low_in_quadrants(paper_layout, tmp_path):
    campaign(tmp_path, paper_layout, 60, 1, seed=5)
    sens = sensitivity_by_position(read_presses(tmp_path))
    x, y = sens["x_mm"].to_numpy(), sens["y_mm"].to_numpy()
    on_edge = np.minimum(np.minimum(x, 30 - x), np.minimum(y, 30 - y)) < 0.5
    centre = np.array([np.hypot(x - cx, y - cy) < 3 for cx in (7.5, 22.5) for cy in (7.5, 22.5)]).any(axis=0)
    assert on_edge.sum() > 3 and centre.sum() > 0
    assert sens["z"][on_edge].min() > sens["z"][centre].max()


def test_plots_are_pngs_of_the_expected_size(paper_layout, tmp_path):
    campaign(tmp_path / "c", paper_layout, 30, 2, seed=6)
    sens = plot_sensitivity_map(tmp_path / "c", tmp_path / "plots" / "sensitivity.png")
    press = plot_press_map(tmp_path / "c", tmp_path / "plots" / "presses.png")
    for png in (sens, press):
        assert png_size(png) == (600, 500) and png.stat().st_size > 20_000
    update_manifest(tmp_path / "c", fsync=False, layout=None)
    with pytest.raises(DataError) as err:
        plot_press_map(tmp_path / "c", tmp_path / "x.png")
    assert err.value.field == "layout"
    assert png_size(plot_press_map(tmp_path / "c", tmp_path / "y.png", layout=paper_layout)) == (600, 500)


def test_the_sensitivity_maps_title_counts_what_it_drew_and_what_it_left_out():
    from neatskin.datasets.plots import sensitivity_title

    df = pd.DataFrame(
        {
            "position_id": [0, 0, 1, 1, 2],
            "x_mm": [1.0, 1.0, 2.0, 2.0, 3.0],
            "y_mm": [0.0, 0.0, 5.0, 5.0, 9.0],
            "flags": [[], ["open_circuit:1-2"], [], [], ["open_circuit:1-3"]],
            "dR_ohm_1_2": [10.0, np.inf, -4.0, -8.0, 999.0],
            "dR_ohm_1_3": [5.0, 5.0, -2.0, -2.0, np.inf],
        }
    )
    title = sensitivity_title(df, sensitivity_by_position(df))  # a press that cut a pair is drawn, not left out
    assert title.splitlines()[1:] == [
        "3 positions, 5 presses",
        "2 presses cut a pair off (dR = inf): 2 positions at the top, marked x",
    ]
    missed = df.assign(flags=[[], ["fsr_missed"], [], [], ["fsr_missed"]])  # flagged for anything else: left out
    title = sensitivity_title(missed, sensitivity_by_position(missed))
    assert title.splitlines()[1:] == [
        "2 positions, 3 presses",
        "2 otherwise flagged presses left out (1 position wholly)",
    ]
    clean = df.iloc[[0, 2, 3]]
    assert sensitivity_title(clean, sensitivity_by_position(clean)).splitlines()[1:] == ["2 positions, 3 presses"]

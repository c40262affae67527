"""The campaign writer: schema, round trips through pandas/pyarrow/DuckDB without the toolkit, durable parts,
resume, waveforms, and a crash-safe idempotent finalize."""

import datetime as dt
import json

import duckdb
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.datasets.reader import feature_matrix, read_metadata, read_presses, read_waveforms
from neatskin.datasets.schema import BASE_COLUMNS, pair_columns, press_schema
from neatskin.datasets.writer import CampaignWriter
from neatskin.errors import DataError
from neatskin.skin.synthetic import synthetic_rows

META = {
    "seed": 7,
    "protocol": {"name": "unit"},
    "layout": {"path": "skins/paper.toml"},
    "wiring": "w.toml",
    "started_at": "2026-11-22T07:00:00+00:00",
}


def expected_frame(rows, pairs):
    """The rows as the DataFrame the files must hold, built independently of the writer."""
    r_cols, dr_cols = pair_columns(pairs)
    records = []
    for row in rows:
        rec = {k: row[k] for k in BASE_COLUMNS}
        rec.update(zip(r_cols, row["R_ohm"]))
        rec.update(zip(dr_cols, row["dR_ohm"]))
        records.append(rec)
    return pd.DataFrame.from_records(records)


def write_all(folder, layout, rows, **kw):
    with CampaignWriter(folder, layout.pairs, META, fsync=False, **kw) as writer:
        for row in rows:
            writer.write_press(row)
        return writer.finalize()


def test_schema_columns_and_types(paper_layout):
    schema = press_schema(paper_layout.pairs, META)
    assert len(schema) == 13 + 2 * 28
    assert schema.names[13] == "R_ohm_1_2" and schema.names[40] == "R_ohm_7_8"
    assert schema.names[41] == "dR_ohm_1_2" and schema.names[-1] == "dR_ohm_7_8"
    assert schema.field("press_id").type == pa.int64() and schema.field("position_id").type == pa.int32()
    assert schema.field("started_at").type == pa.timestamp("us", tz="UTC")
    assert schema.field("flags").type == pa.list_(pa.string())
    meta = schema.metadata
    assert json.loads(meta[b"neatskin.seed"]) == 7
    assert json.loads(meta[b"neatskin.pairs"])[:2] == [[1, 2], [1, 3]]
    assert json.loads(meta[b"neatskin.schema_version"]) == 1


def test_round_trip_without_the_toolkit(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 4, 3, seed=3)
    rows[5]["flags"] = ["fsr_missed", "retried"]
    rows[6]["fsr_peak_n"] = None
    path = write_all(tmp_path / "c", paper_layout, rows)
    want = expected_frame(rows, paper_layout.pairs)

    by_pandas = pd.read_parquet(path)
    by_arrow = pq.read_table(path).to_pandas()
    by_duckdb = duckdb.sql(f"SELECT * FROM read_parquet('{path}') ORDER BY press_id").df()
    for got in (by_pandas, by_arrow, by_duckdb):
        assert list(got.columns) == list(want.columns)
        assert len(got) == 12
        assert got["press_id"].tolist() == list(range(12))
        for col in want.columns:
            if col in ("flags", "started_at", "finished_at"):
                continue
            np.testing.assert_array_equal(
                got[col].to_numpy(dtype=float if col != "campaign" else object),
                want[col].to_numpy(dtype=float if col != "campaign" else object),
            )
        assert [list(f) for f in got["flags"]][5] == ["fsr_missed", "retried"]
        assert pd.isna(got["fsr_peak_n"][6])
    stamps = pd.to_datetime(by_pandas["started_at"], utc=True)
    assert stamps[4] == pd.Timestamp("2026-01-01T00:00:08", tz="UTC")
    meta = pq.read_schema(path).metadata
    assert json.loads(meta[b"neatskin.protocol"]) == {"name": "unit"}
    assert json.loads(meta[b"neatskin.software_version"])
    kv = dict(duckdb.sql(f"SELECT decode(key), decode(value) FROM parquet_kv_metadata('{path}')").fetchall())
    assert json.loads(kv["neatskin.seed"]) == 7


def test_parts_readable_by_pandas_and_duckdb_before_finalize(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 3, 2, seed=1)
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    for row in rows:
        writer.write_press(row)
    (tmp_path / "presses" / ".part-000099.parquet.dead.tmp").write_bytes(b"PAR1 half a file")
    assert len(pd.read_parquet(tmp_path / "presses")) == 6
    n = duckdb.sql(f"SELECT count(*) FROM read_parquet('{tmp_path}/presses/*.parquet')").fetchall()[0][0]
    assert n == 6
    assert read_presses(tmp_path)["press_id"].tolist() == list(range(6))
    assert writer.completed_press_ids() == set(range(6))
    writer.close()


def test_rows_refused_with_the_field_named_and_nothing_written(paper_layout, tmp_path):
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    row = synthetic_rows(paper_layout, 1, 1)[0]
    with pytest.raises(DataError) as err:
        writer.write_press({**row, "R_ohm": row["R_ohm"][:27]})
    assert err.value.field == "R_ohm" and "28 pairs" in str(err.value)
    with pytest.raises(DataError) as err:
        writer.write_press({k: v for k, v in row.items() if k != "x_mm"})
    assert err.value.field == "x_mm"
    with pytest.raises(DataError) as err:
        writer.write_press({**row, "temperature_c": 22.0})
    assert err.value.field == "temperature_c"
    assert list((tmp_path / "presses").iterdir()) == []
    writer.write_press(row)
    with pytest.raises(DataError, match="already durable"):
        writer.write_press(row)
    assert len(list((tmp_path / "presses").iterdir())) == 1


def test_per_column_pair_values_equal_array_form(paper_layout, tmp_path):
    row = synthetic_rows(paper_layout, 1, 1)[0]
    r_cols, dr_cols = pair_columns(paper_layout.pairs)
    flat = {k: v for k, v in row.items() if k not in ("R_ohm", "dR_ohm")}
    flat.update(zip(r_cols, row["R_ohm"]))
    flat.update(zip(dr_cols, row["dR_ohm"]))
    write_all(tmp_path / "a", paper_layout, [row])
    write_all(tmp_path / "b", paper_layout, [flat])
    assert read_presses(tmp_path / "a").equals(read_presses(tmp_path / "b"))


def test_finalize_is_idempotent_and_removes_parts(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 2, seed=2)
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=True)
    for row in reversed(rows):
        writer.write_press(row)
    first = writer.finalize().read_bytes()
    assert list((tmp_path / "presses").iterdir()) == []
    second = writer.finalize().read_bytes()
    assert first == second
    writer.close()
    reopened = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    assert reopened.finalize().read_bytes() == first
    df = read_presses(tmp_path)
    assert df["press_id"].tolist() == list(range(10))
    pd.testing.assert_frame_equal(
        df.drop(columns=["flags"]), read_presses(tmp_path / "presses.parquet").drop(columns=["flags"])
    )


def test_kill_during_finalize_loses_nothing(paper_layout, tmp_path):
    """The two states a kill inside finalize can leave: the consolidated file not yet renamed (a temp file
    beside intact parts), or renamed with only some parts deleted."""
    rows = synthetic_rows(paper_layout, 4, 2, seed=4)
    write_all(tmp_path / "ref", paper_layout, rows)
    reference = read_presses(tmp_path / "ref")

    folder = tmp_path / "c"
    writer = CampaignWriter(folder, paper_layout.pairs, META, fsync=False)
    for row in rows[:5]:
        writer.write_press(row)
    (folder / ".presses.parquet.dead.tmp").write_bytes(b"PAR1 truncated")
    writer.close()
    # state 2: consolidated present, 3 of its 5 parts already deleted, then presses 5..7 written on resume
    writer = CampaignWriter(folder, paper_layout.pairs, META, fsync=False)
    assert not (folder / ".presses.parquet.dead.tmp").exists()
    parts = sorted((folder / "presses").iterdir())
    consolidated = folder / "presses.parquet"
    writer.finalize()
    for p in parts[3:]:
        pq.write_table(pq.read_table(consolidated).slice(int(p.name[5:11]), 1), p)  # restore 2 parts
    writer.close()
    resumed = CampaignWriter(folder, paper_layout.pairs, META, fsync=False)
    assert resumed.completed_press_ids() == set(range(5))
    assert read_presses(folder)["press_id"].tolist() == list(range(5))
    for row in rows[5:]:
        resumed.write_press(row)
    resumed.finalize()
    assert list((folder / "presses").iterdir()) == []
    pd.testing.assert_frame_equal(read_presses(folder), reference)


def test_resume_refuses_a_different_layout(paper_layout, tmp_path):
    write_all(tmp_path, paper_layout, synthetic_rows(paper_layout, 1, 1))
    with pytest.raises(DataError) as err:
        CampaignWriter(tmp_path, paper_layout.pairs[:27], META, fsync=False)
    assert err.value.field == "pairs" and "presses.parquet" in err.value.file


def test_waveforms_partitioned_by_position_and_orphans_removed(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 3, 2, seed=5)
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    signals = {}
    for row in rows:
        t = np.arange(50) + 1000 * row["press_id"]
        signals[row["press_id"]] = {"voltage_v": np.sin(t), "current_a": np.cos(t).astype(np.float32)}
        writer.write_press(row, signals[row["press_id"]])
    writer.close()
    assert sorted(p.name for p in (tmp_path / "waveforms").iterdir()) == [f"position_id={k}" for k in range(3)]
    # an orphan: waveforms written, press part never committed (killed between the two writes)
    orphan = tmp_path / "waveforms" / "position_id=9" / "part-000099.parquet"
    orphan.parent.mkdir()
    pq.write_table(pa.table({"press_id": [99], "sample": [0], "voltage_v": [1.0], "current_a": [1.0]}), orphan)
    CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False).close()
    assert not orphan.exists()
    wf = read_waveforms(tmp_path, [3])
    assert wf["press_id"].unique().tolist() == [3] and wf["position_id"].unique().tolist() == [1]
    np.testing.assert_array_equal(wf["voltage_v"], signals[3]["voltage_v"])
    np.testing.assert_array_equal(wf["sample"], np.arange(50))
    everything = duckdb.sql(
        f"SELECT count(*), count(DISTINCT press_id) FROM "
        f"read_parquet('{tmp_path}/waveforms/*/*.parquet', hive_partitioning=true)"
    ).fetchall()[0]
    assert everything == (300, 6)


def test_waveforms_must_be_aligned(paper_layout, tmp_path):
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    row = synthetic_rows(paper_layout, 1, 1)[0]
    with pytest.raises(DataError) as err:
        writer.write_press(row, {"voltage_v": np.zeros(10), "current_a": np.zeros(11)})
    assert err.value.field == "waveforms"
    assert writer.completed_press_ids() == set()


def test_feature_matrix_and_metadata(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 3, 2, seed=6)
    rows[1]["flags"] = ["clipped"]
    write_all(tmp_path, paper_layout, rows)
    df = read_presses(tmp_path)
    X, y, groups = feature_matrix(df)
    assert X.shape == (6, 28) and y.shape == (6, 2)
    np.testing.assert_array_equal(X[4], rows[4]["dR_ohm"])
    assert y[4].tolist() == [rows[4]["x_mm"], rows[4]["y_mm"]]
    assert groups.tolist() == [0, 0, 1, 1, 2, 2]
    assert feature_matrix(df, exclude_flagged=True)[0].shape == (5, 28)
    meta = read_metadata(tmp_path)
    assert meta["seed"] == 7 and meta["pairs"][-1] == [7, 8] and df.attrs["neatskin"]["wiring"] == "w.toml"


def test_timestamps_accept_epoch_seconds_and_naive_utc(paper_layout, tmp_path):
    row = synthetic_rows(paper_layout, 1, 1)[0]
    row["started_at"] = dt.datetime(2026, 3, 1, 12, 0, 0, 250)
    row["finished_at"] = dt.datetime(2026, 3, 1, 12, 0, 1, tzinfo=dt.UTC).timestamp()
    write_all(tmp_path, paper_layout, [row])
    df = read_presses(tmp_path)
    assert df["started_at"][0] == pd.Timestamp("2026-03-01T12:00:00.000250", tz="UTC")
    assert df["finished_at"][0] == pd.Timestamp("2026-03-01T12:00:01", tz="UTC")


def test_out_of_range_value_names_the_field(paper_layout, tmp_path):
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False)
    row = synthetic_rows(paper_layout, 1, 1)[0]
    with pytest.raises(DataError) as err:
        writer.write_press({**row, "position_id": 2**40})
    assert err.value.field == "position_id" and "int32" in str(err.value)
    with pytest.raises(DataError) as err:
        writer.write_press({**row, "started_at": "yesterday"})
    assert err.value.field == "started_at"


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(allow_nan=False, width=64), min_size=56, max_size=56), st.integers(0, 10**9))
def test_pair_values_round_trip_bit_for_bit(paper_layout, tmp_path_factory, values, press_id):
    folder = tmp_path_factory.mktemp("prop")
    row = synthetic_rows(paper_layout, 1, 1)[0]
    row.update(press_id=press_id, R_ohm=np.array(values[:28]), dR_ohm=np.array(values[28:]))
    write_all(folder, paper_layout, [row])
    got = pq.read_table(folder / "presses.parquet")
    assert got.column("press_id").to_pylist() == [press_id]
    back = np.array([got.column(c)[0].as_py() for c in got.column_names[13:]])
    np.testing.assert_array_equal(back.view(np.int64), np.array(values).view(np.int64))  # -0.0 and inf too

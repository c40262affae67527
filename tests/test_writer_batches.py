"""Batched parts (the dry run's writer): the part contract (named after the first press id, ids strictly
increasing), what is durable and what is only batched, the batch encoder against the one-row one, recovery
of multi-row parts and what it refuses, and a finalize whose output does not depend on the batching."""

import shutil

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses, read_waveforms
from neatskin.datasets.schema import RowEncoder, press_schema
from neatskin.datasets.writer import CampaignWriter, dry_run_batch_presses
from neatskin.errors import DataError
from neatskin.skin.synthetic import synthetic_rows

META = {"seed": 7, "campaign": "synthetic", "protocol": {"name": "unit"}}


def write(folder, layout, rows, **kw):
    with CampaignWriter(folder, layout.pairs, META, fsync=False, **kw) as writer:
        for row in rows:
            writer.write_press(row)
        return writer.finalize()


def part_ids(folder) -> dict[int, list[int]]:
    return {k: pq.read_table(p).column("press_id").to_pylist() for k, p in press_parts(folder).items()}


def parquet_bytes(table: pa.Table) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, use_dictionary=False)
    return sink.getvalue().to_pybytes()


def test_dry_run_batch_sizes():
    assert [dry_run_batch_presses(n) for n in (12, 120, 511, 512, 2800, 28000)] == [1, 1, 1, 256, 256, 256]


def test_a_batch_is_one_part_named_after_its_first_press(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 5, 3, seed=1)  # 15 presses
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False, batch_presses=4, batch_s=3600)
    paths = [writer.write_press(row) for row in rows[:6]]
    assert [p.name for p in paths] == ["part-000000.parquet"] * 4 + ["part-000004.parquet"] * 2
    assert part_ids(tmp_path) == {0: [0, 1, 2, 3]}
    assert writer.completed_press_ids() == {0, 1, 2, 3} and writer.batched_press_ids() == {4, 5}
    with pytest.raises(DataError, match="already written .in the batch") as err:
        writer.write_press(rows[5])
    assert err.value.field == "press_id"
    with pytest.raises(DataError, match="already durable"):
        writer.write_press(rows[2])
    assert writer.flush().name == "part-000004.parquet" and writer.flush() is None
    assert writer.completed_press_ids() == set(range(6)) and writer.batched_press_ids() == set()
    for row in rows[6:]:
        writer.write_press(row)
    writer.close()  # close writes the batch
    assert part_ids(tmp_path) == {0: [0, 1, 2, 3], 4: [4, 5], 6: [6, 7, 8, 9], 10: [10, 11, 12, 13], 14: [14]}
    assert set(writer.part_sha256) == {0, 4, 6, 10, 14}


def test_a_batch_is_written_after_batch_s_whatever_its_size(paper_layout, tmp_path):
    now = [0.0]
    rows = synthetic_rows(paper_layout, 4, 2, seed=2)
    writer = CampaignWriter(
        tmp_path, paper_layout.pairs, META, fsync=False, batch_presses=100, batch_s=1.0, clock=lambda: now[0]
    )
    for row in rows[:3]:
        writer.write_press(row)
        now[0] += 0.4  # the third press lands 0.8 s after the first: still batched
    assert part_ids(tmp_path) == {}
    writer.write_press(rows[3])  # 1.2 s after the batch began
    assert part_ids(tmp_path) == {0: [0, 1, 2, 3]}
    writer.write_press(rows[4])
    assert writer.batched_press_ids() == {4}
    writer.close()


def test_a_lower_press_id_starts_a_new_part(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 3, 2, seed=3)
    order = [rows[i] for i in (2, 3, 0, 1, 5, 4)]
    with CampaignWriter(tmp_path / "b", paper_layout.pairs, META, fsync=False, batch_presses=10) as writer:
        for row in order:
            writer.write_press(row)
        writer.flush()
        assert part_ids(tmp_path / "b") == {2: [2, 3], 0: [0, 1, 5], 4: [4]}  # interleaved parts
        writer.finalize()
    assert read_presses(tmp_path / "b")["press_id"].tolist() == list(range(6))


def test_finalize_gives_the_same_file_whatever_the_batching(paper_layout, tmp_path, monkeypatch):
    import neatskin.datasets.consolidate as consolidate_module

    monkeypatch.setattr(consolidate_module, "FINALIZE_BATCH", 16)  # several row groups from few rows
    rows = synthetic_rows(paper_layout, 10, 5, seed=4)  # 50 presses
    rows[7]["flags"] = ["clipped:1-2"]
    rows[8]["fsr_peak_n"] = None
    files = {b: write(tmp_path / f"b{b}", paper_layout, rows, batch_presses=b).read_bytes() for b in (1, 3, 7, 64)}
    assert len(set(files.values())) == 1
    handle = pq.ParquetFile(tmp_path / "b7" / "presses.parquet")
    assert [handle.metadata.row_group(k).num_rows for k in range(handle.num_row_groups)] == [16, 16, 16, 2]
    assert not list((tmp_path / "b7" / "presses").iterdir())


def test_finalize_reads_back_about_one_row_group_at_a_time(paper_layout, tmp_path, monkeypatch):
    import neatskin.datasets.consolidate as consolidate_module

    monkeypatch.setattr(consolidate_module, "FINALIZE_BATCH", 16)
    rows = synthetic_rows(paper_layout, 10, 5, seed=4)  # 50 presses in parts of 7 (the last of 1)
    writer = CampaignWriter(tmp_path, paper_layout.pairs, META, fsync=False, batch_presses=7, batch_s=3600)
    for row in rows:
        writer.write_press(row)
    writer.flush()
    groups = consolidate_module.read_groups(press_parts(tmp_path), writer._part_last)
    sizes = [sum(len(part_ids(tmp_path)[int(p.stem[5:])]) for p in group) for group in groups]
    assert sizes == [21, 21, 8]  # closed once they may hold 16 rows: never the whole campaign at once
    writer.finalize()
    writer.close()
    assert pd.read_parquet(tmp_path / "presses.parquet").press_id.tolist() == list(range(50))


def test_the_batch_encoder_equals_one_row_encoding(paper_layout):
    encoder = RowEncoder(press_schema(paper_layout.pairs, META))
    rows = synthetic_rows(paper_layout, 4, 3, seed=5)
    rows[1]["flags"] = ["a", "b"]
    rows[2]["fsr_onset_s"] = None
    rows[3]["R_ohm"] = np.array([np.nan, np.inf, -0.0, *rows[3]["R_ohm"][3:]])
    batch = encoder.rows_table(rows)
    one_by_one = pa.concat_tables([encoder.table(row) for row in rows])
    assert batch.num_rows == 12 and batch.schema.equals(one_by_one.schema, check_metadata=True)
    assert parquet_bytes(batch) == parquet_bytes(one_by_one.combine_chunks())  # NaN, inf and -0.0 bit for bit
    assert batch.column("flags").to_pylist()[1] == ["a", "b"] and batch.column("fsr_onset_s")[2].as_py() is None
    r12 = batch.column("R_ohm_1_2").to_numpy()
    assert np.isnan(r12[3]) and batch.column("R_ohm_1_3")[3].as_py() == np.inf
    # a bad row in a batch: the error one-row encoding gives, for the first bad row
    bad = [*rows[:2], {**rows[2], "position_id": 2**40}, {**rows[3], "x_mm": None}]
    with pytest.raises(DataError) as in_batch:
        encoder.rows_table(bad)
    with pytest.raises(DataError) as alone:
        encoder.table(bad[2])
    assert str(in_batch.value) == str(alone.value) and in_batch.value.field == "position_id"
    assert "does not fit int32" in str(alone.value)
    with pytest.raises(DataError, match="'x_mm' is None"):
        encoder.rows_table(bad[3:])


def test_a_killed_batch_is_lost_and_resume_writes_it_again(paper_layout, tmp_path):
    """A writer that dies with presses in its batch (no close: a SIGKILL) leaves only the full parts and
    orphan waveforms; reopened, it resumes those presses and the result equals an uninterrupted write."""
    rows = synthetic_rows(paper_layout, 6, 3, seed=6)  # 18 presses
    signals = {r["press_id"]: {"voltage_v": np.full(20, float(r["press_id"]))} for r in rows}
    with CampaignWriter(tmp_path / "ref", paper_layout.pairs, META, fsync=False) as writer:
        for row in rows:
            writer.write_press(row, signals[row["press_id"]])
        writer.finalize()
    reference = read_presses(tmp_path / "ref")

    folder = tmp_path / "c"
    writer = CampaignWriter(folder, paper_layout.pairs, META, fsync=False, batch_presses=5, batch_s=3600)
    for row in rows[:13]:
        writer.write_press(row, signals[row["press_id"]])
    assert writer.completed_press_ids() == set(range(10))
    writer._close_dir()  # dropped with presses 10..12 in its batch, as a kill would
    del writer
    assert part_ids(folder) == {0: [0, 1, 2, 3, 4], 5: [5, 6, 7, 8, 9]}

    resumed = CampaignWriter(folder, paper_layout.pairs, META, fsync=False, batch_presses=5)
    assert resumed.completed_press_ids() == set(range(10))
    assert len(list((folder / "waveforms").rglob("part-*.parquet"))) == 10  # orphans of 10..12 removed
    for row in rows:
        if row["press_id"] not in resumed.completed_press_ids():
            resumed.write_press(row, signals[row["press_id"]])
    resumed.finalize()
    resumed.close()
    pd.testing.assert_frame_equal(read_presses(folder), reference)
    wf = read_waveforms(folder)
    assert (wf.groupby("press_id")["voltage_v"].first().to_numpy() == np.arange(18)).all()


def _batched_folder(layout, folder, rows, batch=4):
    with CampaignWriter(folder, layout.pairs, META, fsync=False, batch_presses=batch) as writer:
        for row in rows:
            writer.write_press(row)
    return press_parts(folder)


def test_recovery_accepts_multi_row_parts_and_refuses_what_breaks_the_contract(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 4, 3, seed=7)  # 12 presses, parts of 4
    parts = _batched_folder(paper_layout, tmp_path / "ok", rows)
    assert sorted(parts) == [0, 4, 8]
    assert CampaignWriter(tmp_path / "ok", paper_layout.pairs, META, fsync=False).completed_press_ids() == set(
        range(12)
    )

    def broken(name, change):
        folder = tmp_path / name
        shutil.copytree(tmp_path / "ok", folder)
        change(press_parts(folder))
        with pytest.raises(DataError) as err:
            CampaignWriter(folder, paper_layout.pairs, META, fsync=False)
        return err.value

    def misnamed(parts):  # ids 4..7 under the name of press 5
        parts[4].rename(parts[4].with_name("part-000005.parquet"))

    err = broken("misnamed", misnamed)
    assert err.field == "press_id" and err.file.endswith("part-000005.parquet") and "[4, 5, 6, 7]" in str(err)

    def unsorted(parts):
        table = pq.read_table(parts[4])
        pq.write_table(table.take([0, 2, 1, 3]), parts[4])

    err = broken("unsorted", unsorted)
    assert err.field == "press_id" and "strictly increase" in str(err) and "press 6 then 5" in str(err)

    def copied(parts):  # part 0 split into [0, 1, 2] and [3, 5, 6]: presses 5 and 6 are also in part 4
        first = pq.read_table(parts[0])
        again = pa.concat_tables([first.slice(3, 1), pq.read_table(parts[4]).slice(1, 2)])
        pq.write_table(again, parts[0].with_name("part-000003.parquet"))
        pq.write_table(first.slice(0, 3), parts[0])

    err = broken("copied", copied)
    assert err.field == "press_id" and "[5, 6]" in str(err) and "another part" in str(err)

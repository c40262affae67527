"""Loading a dataset for the baselines: only the columns they use, the same arrays as the full reader gives,
and groups that follow the physical position ids of a merged dataset."""

import numpy as np
import pyarrow.parquet as pq
from conftest import PROTOCOLS

from neatskin.baselines.dataset import load_baseline_data
from neatskin.datasets.curate import merge
from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.reader import read_presses
from neatskin.datasets.writer import CampaignWriter
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_REF = {"path": str(PROTOCOLS / "skins" / "paper.toml"), "name": "neatskin-paper"}


def campaign(folder, layout, rows, seed, finalize=True):
    create_manifest(folder, fsync=False, campaign=rows[0]["campaign"], seed=seed, layout=LAYOUT_REF)
    with CampaignWriter(folder, layout.pairs, {"seed": seed, "layout": LAYOUT_REF}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        if finalize:
            writer.finalize()
    update_manifest(folder, fsync=False, status="complete", counts={"planned": len(rows), "completed": len(rows)})
    return folder


def test_arrays_equal_those_of_the_full_reader(paper_layout, tmp_path):
    rows = synthetic_rows(paper_layout, 6, 4, seed=3, campaign="a")
    rows[5]["flags"] = ["fsr_missed"]
    folder = campaign(tmp_path / "a", paper_layout, rows, seed=3)
    # a press both in presses.parquet and in a part (a kill during finalize's cleanup) counts once
    pq.write_table(pq.read_table(folder / "presses.parquet").slice(7, 1), folder / "presses" / "part-000007.parquet")
    data = load_baseline_data(folder)
    df = read_presses(folder)
    kept = df[[len(f) == 0 for f in df["flags"]]]
    pairs = [f"dR_ohm_{p.i}_{p.j}" for p in paper_layout.pairs]
    assert data.pair_columns == tuple(pairs) and data.n_flagged_dropped == 1
    assert data.X.dtype == np.float64 and data.X.shape == (23, 28)
    np.testing.assert_array_equal(data.X, kept[pairs].to_numpy())
    np.testing.assert_array_equal(data.y, kept[["x_mm", "y_mm"]].to_numpy())
    np.testing.assert_array_equal(data.groups, kept["position_id"].to_numpy())


def test_merged_dataset_groups_by_physical_position(paper_layout, tmp_path):
    """Two campaigns pressing the same 5 spots: `dataset merge` gives the spots one id each, and the grouped
    split must keep both campaigns' presses of a spot on one side (5 groups, not 10)."""
    a = synthetic_rows(paper_layout, 5, 3, seed=4, campaign="a")
    b = synthetic_rows(paper_layout, 5, 2, seed=4, campaign="b")
    campaign(tmp_path / "a", paper_layout, a, seed=4)
    campaign(tmp_path / "b", paper_layout, b, seed=4)
    data = load_baseline_data(merge([tmp_path / "a", tmp_path / "b"], tmp_path / "m"))
    assert len(data.y) == 25
    assert data.groups.tolist() == [r["position_id"] for r in a] + [r["position_id"] for r in b]
    assert len(np.unique(data.groups)) == 5

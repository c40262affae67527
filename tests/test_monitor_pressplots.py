"""Curator plots (neatskin.datasets.pressplots): one press's R per pair and FSR against time from waveforms or
features, and the baseline drift per pair against press order."""

from __future__ import annotations

import json
import shutil
import struct
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from neatskin.datasets.pressplots import baseline_drift_pct, cut_off, drift_title, plot_drift, plot_press, press_series
from neatskin.datasets.reader import read_presses
from neatskin.errors import DataError
from neatskin.tomlfile import resolve_path


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path_factory.mktemp("plots") / "smoke"
    run_campaign(load_protocol(resolve_path("protocols/smoke.toml")), folder, progress=False, report=False)
    return folder


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_press_series_from_waveforms_matches_the_stored_row(campaign):
    df = read_presses(campaign)
    row = df[df["press_id"] == 3].iloc[0]
    s = press_series(campaign, 3)
    assert s.source == "waveforms" and len(s.pairs) == 28 and s.pairs[0] == "1-2"
    sweeps = json.loads((campaign / "manifest.json").read_text())["sweep"]["sweeps_per_press"]
    assert s.resistance_ohm.shape == (sweeps, 28) and s.time_s.shape == (sweeps,)
    assert np.all(np.diff(s.time_s) > 0)
    stored_r = np.array([row[f"R_ohm_{p.replace('-', '_')}"] for p in s.pairs])
    stored_base = stored_r - np.array([row[f"dR_ohm_{p.replace('-', '_')}"] for p in s.pairs])
    np.testing.assert_allclose(s.resistance_ohm[0], stored_base, rtol=1e-3)  # first sweep: before contact
    closest = np.abs(s.resistance_ohm - stored_r).min(axis=0) / stored_r  # a sweep on the hold's plateau
    assert closest.max() < 1e-3
    assert s.fsr_unit == "V" and len(s.fsr) == sweeps * 3416 and s.fsr.max() > 1.0 > s.fsr[0]
    assert s.onset_s == pytest.approx(row["fsr_onset_s"]) and s.offset_s == pytest.approx(row["fsr_offset_s"])


def test_press_series_from_features_without_waveforms(campaign, tmp_path):
    folder = tmp_path / "features"
    shutil.copytree(campaign, folder, ignore=shutil.ignore_patterns("waveforms"))
    s = press_series(folder, 3)
    row = read_presses(folder).set_index("press_id").loc[3]
    assert s.source == "features" and s.resistance_ohm.shape == (6, 28)
    assert s.resistance_ohm[2, 0] == row["R_ohm_1_2"] and s.resistance_ohm[0, 0] == row["R_ohm_1_2"] - row["dR_ohm_1_2"]
    assert s.time_s[1] == row["fsr_onset_s"] and s.fsr.max() == row["fsr_peak_n"]


def test_the_manifest_records_the_mux_visiting_order(campaign):
    from neatskin.acquisition.wiring import load_wiring
    from neatskin.layout import load_layout

    sweep = json.loads((campaign / "manifest.json").read_text())["sweep"]
    wiring = load_wiring(campaign / "inputs" / "wiring.toml", load_layout(campaign / "inputs" / "layout.toml"))
    assert sweep["pair_order"] == list(range(28))  # the sweep's "pairs" order: layout.pairs order
    # slot k's chip and address are those the board file wires pair pair_order[k] to
    routes = [(wiring.routes[p].chip, wiring.routes[p].address) for p in sweep["pair_order"]]
    assert list(zip(sweep["mux_chip"], sweep["mux_address"])) == routes
    assert len(set(routes)) == 28 and len(set(sweep["mux_chip"])) == 7  # 7 chips, 4 pairs each


def test_a_wrong_pair_order_is_caught_not_drawn(campaign, tmp_path):
    folder = tmp_path / "reordered"
    shutil.copytree(campaign, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["sweep"]["pair_order"] = list(range(27, -1, -1))
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataError, match=r"sweep.pair_order"):
        press_series(folder, 3)


def test_unknown_press_id_names_the_range(campaign):
    with pytest.raises(DataError, match=r"no press 99 .*between 0 and 11"):
        press_series(campaign, 99)


def test_baseline_drift_is_r_minus_dr_against_the_first_press(campaign):
    df = read_presses(campaign)
    ids, labels, pct = baseline_drift_pct(df)
    assert ids.tolist() == list(range(12)) and labels[-1] == "7-8" and pct.shape == (12, 28)
    base = df["R_ohm_7_8"].to_numpy() - df["dR_ohm_7_8"].to_numpy()
    np.testing.assert_allclose(pct[:, -1], 100 * (base / base[0] - 1))
    assert np.all(pct[0] == 0.0)


def test_drift_leaves_out_the_presses_that_cut_a_pair_off_and_says_so(campaign, tmp_path):
    """A press that cuts a pair off stores R = dR = +inf: R - dR was inf - inf (numpy's 'invalid value encountered in
    subtract' on every paper dry run), and a pair cut on the first press lost its whole line. Now those values are
    gaps, each pair's reference is its first uncut press, and the title counts what was left out."""
    table = pq.read_table(campaign / "presses.parquet")
    r, dr = table.column("R_ohm_1_2").to_numpy().copy(), table.column("dR_ohm_1_2").to_numpy().copy()
    base = r - dr
    r[[0, 4]] = dr[[0, 4]] = np.inf  # pair 1-2 cut off by presses 0 (the old reference) and 4
    flags = table.column("flags").to_pylist()
    for k in (0, 4):
        flags[k] = [*flags[k], "open_circuit:1-2", "clipped:1-2"]
    for name, values in (("R_ohm_1_2", r), ("dR_ohm_1_2", dr)):
        table = table.set_column(table.schema.get_field_index(name), name, pa.array(values))
    table = table.set_column(table.schema.get_field_index("flags"), "flags", pa.array(flags, pa.list_(pa.string())))
    (tmp_path / "cut").mkdir()
    pq.write_table(table, tmp_path / "cut" / "presses.parquet")
    df = read_presses(tmp_path / "cut")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the old inf - inf warned
        ids, labels, pct = baseline_drift_pct(df)
        written = plot_drift(tmp_path / "cut", tmp_path / "drift.png")
    assert _png_size(written) == (900, 450)
    assert labels[0] == "1-2" and np.isnan(pct[[0, 4], 0]).all()
    kept = np.array([k not in (0, 4) for k in range(12)])
    np.testing.assert_allclose(pct[kept, 0], 100 * (base[kept] / base[1] - 1))  # press 1: the first uncut one
    assert pct[1, 0] == 0.0 and np.isfinite(pct[:, 1:]).all()
    np.testing.assert_array_equal(pct[:, 1:], baseline_drift_pct(read_presses(campaign))[2][:, 1:])  # others alike
    cut = cut_off(df)
    assert cut.sum() == 2 and cut[[0, 4], 0].all()
    title = drift_title(labels, pct, cut)
    assert "left out: 2 values where the press cut the pair off (R = inf; 2 presses, 1 pair)" in title
    assert "left out" not in drift_title(
        *baseline_drift_pct(read_presses(campaign))[1:], cut_off(read_presses(campaign))
    )


def test_a_press_that_cut_every_pair_off_is_a_gap_in_the_median_too(campaign, tmp_path):
    table = pq.read_table(campaign / "presses.parquet")
    for name in table.column_names:
        if name.startswith(("R_ohm_", "dR_ohm_")):
            values = table.column(name).to_numpy().copy()
            values[3] = np.inf
            table = table.set_column(table.schema.get_field_index(name), name, pa.array(values))
    (tmp_path / "cut").mkdir()
    pq.write_table(table, tmp_path / "cut" / "presses.parquet")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "All-NaN slice encountered" for the median of press 3
        assert _png_size(plot_drift(tmp_path / "cut", tmp_path / "drift.png")) == (900, 450)
    _, _, pct = baseline_drift_pct(read_presses(tmp_path / "cut"))
    assert np.isnan(pct[3]).all() and np.isfinite(np.delete(pct, 3, axis=0)).all()
    assert "left out: 28 values where the press cut the pair off (R = inf; 1 press, 28 pairs)" in drift_title(
        tuple(range(28)), pct, cut_off(read_presses(tmp_path / "cut"))
    )


def test_plots_are_written(campaign, tmp_path):
    assert _png_size(plot_press(campaign, 3, tmp_path / "press-3.png")) == (900, 650)
    assert _png_size(plot_drift(campaign, tmp_path / "drift.png")) == (900, 450)

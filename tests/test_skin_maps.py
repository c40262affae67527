"""Sensitivity maps: the paper's qualitative findings as assertions, and `neatskin skin maps` end to end."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from neatskin.cli import main
from neatskin.layout import ElectrodePair
from neatskin.skin.maps import SensitivityMap, deformation_sensitivity, grid_positions_mm, paper_sensitivity
from neatskin.skin.model import SkinModel


@pytest.fixture(scope="module")
def paper_map(paper_layout):
    return paper_sensitivity(paper_layout)


@pytest.fixture(scope="module")
def dense_map(paper_layout):
    x, y = grid_positions_mm(paper_layout, 0.5)
    return deformation_sensitivity(SkinModel(paper_layout), x, y, depth_mm=3.5)


def _channel_between(layout, i, j):
    a, b = (layout.electrodes[layout.electrode_index[k]].junction for k in (i, j))
    return next(k for k, c in enumerate(layout.channels) if {c.a, c.b} == {a, b})


def test_adjacent_pairs_sensitive_along_their_shortest_path_only(paper_layout, paper_map):
    adjacent = paper_layout.pair_classes[0]  # the class of (1,2): the 8 neighbours around the boundary
    assert len(adjacent) == 8
    for pair in adjacent:
        dr = paper_map.delta_ohm[:, paper_layout.pairs.index(pair)]
        path = _channel_between(paper_layout, pair.i, pair.j)
        assert int(np.argmax(dr)) == path
        assert np.all(np.delete(dr, path) < 0.25 * dr[path])  # "little elsewhere"


def test_every_channel_change_is_seen_by_some_pair(paper_layout, paper_map):
    base = SkinModel(paper_layout).baseline_pair_resistance_ohm
    seen = np.max(paper_map.delta_ohm / base, axis=1)  # per channel: the largest relative change
    assert seen.shape == (12,) and np.all(seen > 0.05)
    assert np.all(paper_map.delta_ohm > -1e-9 * base)  # Rayleigh: +50 % never lowers an R_eq


def test_paper_map_z_is_normalised_and_periphery_beats_centre(paper_layout, paper_map):
    z = paper_map.z
    assert np.max(np.abs(z)) == 1.0
    inner = [
        k
        for k, c in enumerate(paper_layout.channels)
        if paper_layout.junctions[c.a].name == "J11" or paper_layout.junctions[c.b].name == "J11"
    ]
    outer = [k for k in range(12) if k not in inner]
    assert np.all(z[outer] == pytest.approx(1.0)) and np.all(z[inner] < 0.6)


def test_quadrant_centres_are_the_least_sensitive_points(paper_layout, dense_map):
    z = dense_map.z
    centres = np.array([paper_layout.xy_mm[list(face)].mean(axis=0) for face in paper_layout.faces])
    at_centre = [int(np.argmin(np.hypot(dense_map.x_mm - cx, dense_map.y_mm - cy))) for cx, cy in centres]
    # the four smallest values on the whole map are exactly the four quadrant centres
    assert set(np.argsort(z)[:4].tolist()) == set(at_centre)
    assert np.all(z[at_centre] < 0.05)  # near zero, as the paper measured (Fig. 8)
    on_channels = np.isclose(dense_map.y_mm, 0.0) | np.isclose(dense_map.x_mm, 0.0)
    assert np.min(z[on_channels]) > 0.5


def test_pairs_with_equal_paths_see_larger_regions(paper_layout, dense_map):
    def area(pair):
        return np.mean(dense_map.pair_normalised(ElectrodePair(*pair)) > 0.5)

    adjacent = area((1, 2))
    for pair in [(2, 6), (1, 3), (1, 4), (1, 5)]:
        assert area(pair) > adjacent


def test_cli_maps_writes_pngs_and_parquet(tmp_path, paper_layout, protocols_dir, capsys):
    out = tmp_path / "maps"
    code = main(
        [
            "skin",
            "maps",
            "--layout",
            str(protocols_dir / "skins" / "paper.toml"),
            "--out",
            str(out),
            "--grid-step-mm",
            "1.0",
            "--no-progress",
        ]
    )
    assert code == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "deformation_pairs.png",
        "deformation_z.png",
        "paper_pairs.png",
        "paper_z.png",
        "sensitivity_maps.parquet",
    ]
    for png in out.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    frame = pd.read_parquet(out / "sensitivity_maps.parquet")
    assert len(frame) == 12 + 31 * 31  # 12 channel midpoints + the 1 mm grid over 30 x 30 mm
    assert list(frame.columns[:4]) == ["source", "x_mm", "y_mm", "z"]
    assert [c for c in frame.columns if c.startswith("dR_ohm_")] == [f"dR_ohm_{p.i}_{p.j}" for p in paper_layout.pairs]
    assert frame["z"].abs().groupby(frame["source"]).max().tolist() == [1.0, 1.0]
    meta = pq.read_schema(out / "sensitivity_maps.parquet").metadata
    assert meta[b"neatskin.depth_mm"] == b"3.5" and meta[b"neatskin.fidelity"] == b"deformation"
    assert str(out / "paper_z.png") in capsys.readouterr().out


def test_cli_maps_bad_input_names_the_problem(tmp_path, capsys):
    assert main(["skin", "maps", "--layout", str(tmp_path / "missing.toml"), "--out", str(tmp_path)]) == 3
    assert "missing.toml" in capsys.readouterr().err
    assert main(["skin", "maps", "--grid-step-mm", "0", "--out", str(tmp_path)]) == 3
    assert "--grid-step-mm" in capsys.readouterr().err


def test_cli_press_prints_every_pair(capsys, paper_layout):
    assert main(["skin", "press", "--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "3.5"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("press at (7.5, 0) mm, depth 3.5 mm, force 3.25 N")
    rows = {line.split()[0]: [float(v) for v in line.split()[1:]] for line in lines[2:]}
    assert list(rows) == [p.label for p in paper_layout.pairs]
    assert rows["1-2"][0] == pytest.approx(17 / 24 * 3750, abs=1e-3)
    assert max(rows, key=lambda k: rows[k][2]) == "1-8"  # the press sits on channel 8-1
    assert main(["skin", "press", "--x-mm", "nan", "--y-mm", "0"]) == 3
    assert "--x-mm" in capsys.readouterr().err


def test_sensitivity_map_is_a_frozen_validated_value(paper_layout, paper_map):
    pairs = paper_layout.pairs
    x, y = np.zeros(3), np.ones(3)
    made = SensitivityMap("s", x, y, np.zeros((3, len(pairs))), pairs)
    assert made.source == "s" and made.x_mm is x and made.y_mm is y and made.pairs is pairs
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.source = "t"  # type: ignore[misc]
    for bad_y, bad_delta in ((np.ones(2), np.zeros((3, len(pairs)))), (y, np.zeros((3, len(pairs) - 1)))):
        with pytest.raises(ValueError, match="inconsistent map shapes"):
            SensitivityMap("s", x, bad_y, bad_delta, pairs)
    same = SensitivityMap(paper_map.source, paper_map.x_mm, paper_map.y_mm, paper_map.delta_ohm, pairs)
    assert repr(same) == repr(paper_map) and same.source == "paper_plus50pct"
    assert paper_sensitivity(paper_layout, 0.25).source == "paper_plus25pct"

"""Press positions: deterministic from the seed, on a channel or inside a face, stratified coverage."""

import math
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.errors import ConfigError
from neatskin.gcode.positions import PositionSpec, generate_positions
from neatskin.layout import layout_from_dict


def grid_layout(n: int, pitch_mm: float = 10.0, width_mm: float = 2.0):
    """An n x n junction grid with electrodes on the boundary, built here (not from the paper's file)."""
    names = {(i, j): f"J{i}_{j}" for i in range(n) for j in range(n)}
    junctions = [{"name": names[i, j], "x_mm": i * pitch_mm, "y_mm": j * pitch_mm} for j in range(n) for i in range(n)]
    channels = [{"from": names[i, j], "to": names[i + 1, j]} for j in range(n) for i in range(n - 1)]
    channels += [{"from": names[i, j], "to": names[i, j + 1]} for i in range(n) for j in range(n - 1)]
    boundary = [names[i, j] for (i, j) in names if i in (0, n - 1) or j in (0, n - 1)]
    electrodes = [{"number": k + 1, "junction": name} for k, name in enumerate(boundary)]
    return layout_from_dict(
        {
            "skin": {"name": f"grid{n}", "thickness_mm": 5.5, "channel_depth_mm": 2.0, "resistivity_ohm_m": 0.5},
            "channel_defaults": {"width_mm": width_mm, "height_mm": 1.0},
            "junctions": junctions,
            "channels": channels,
            "electrodes": electrodes,
        }
    )


def triangle_layout():
    """A square with one diagonal: two triangular faces, a 21.2 mm channel."""
    j = [
        {"name": "a", "x_mm": 0, "y_mm": 0},
        {"name": "b", "x_mm": 15, "y_mm": 0},
        {"name": "c", "x_mm": 15, "y_mm": 15},
        {"name": "d", "x_mm": 0, "y_mm": 15},
    ]
    ch = [
        {"from": "a", "to": "b"},
        {"from": "b", "to": "c"},
        {"from": "c", "to": "d"},
        {"from": "d", "to": "a"},
        {"from": "a", "to": "c"},
    ]
    el = [{"number": k + 1, "junction": n} for k, n in enumerate("abcd")]
    return layout_from_dict(
        {
            "skin": {"name": "tri", "thickness_mm": 5.5, "channel_depth_mm": 2.0, "resistivity_ohm_m": 0.5},
            "channel_defaults": {"width_mm": 2.0, "height_mm": 1.0},
            "junctions": j,
            "channels": ch,
            "electrodes": el,
        }
    )


def on_channel_or_in_face(layout, x, y) -> bool:
    """Oracle written independently of positions.py: point-segment distance and a ray-casting polygon test."""
    for ch in layout.channels:
        (ax, ay), (bx, by) = layout.xy_mm[ch.a], layout.xy_mm[ch.b]
        t = max(0.0, min(1.0, ((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / ((bx - ax) ** 2 + (by - ay) ** 2)))
        if math.hypot(x - ax - t * (bx - ax), y - ay - t * (by - ay)) <= ch.width_mm / 2 + 1e-9:
            return True
    for face in layout.faces:
        poly = layout.xy_mm[list(face)]
        inside = False
        for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0)):
            if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                inside = not inside
        if inside:
            return True
    return False


LAYOUTS = {"grid4": grid_layout(4), "grid2": grid_layout(2, 20.0), "tri": triangle_layout()}


def test_same_seed_same_positions_other_seed_other_positions(paper_layout):
    a = generate_positions(paper_layout, PositionSpec("paper", 100, 2019))
    b = generate_positions(paper_layout, PositionSpec("paper", 100, 2019))
    c = generate_positions(paper_layout, PositionSpec("paper", 100, 2020))
    assert a == b
    assert a.x_mm != c.x_mm
    assert len(a) == 100 and a.ids == tuple(range(100))


def test_paper_positions_on_channels_or_in_quadrants(paper_layout):
    ps = generate_positions(paper_layout, PositionSpec("paper", 100, 2019))
    assert all(on_channel_or_in_face(paper_layout, x, y) for x, y in zip(ps.x_mm, ps.y_mm))
    kinds = Counter(f.split(":")[0] for f in ps.features)
    assert set(kinds) == {"channel", "face"}  # both kinds occur in 100 draws
    # channel strips are 2 mm wide, so nothing lies more than 1 mm outside the 30 mm square
    assert min(ps.x_mm + ps.y_mm) >= -1.0 and max(ps.x_mm + ps.y_mm) <= 31.0


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(sorted(LAYOUTS)), st.integers(1, 60))
def test_paper_strategy_property_over_seeds_and_layouts(seed, name, count):
    layout = LAYOUTS[name]
    ps = generate_positions(layout, PositionSpec("paper", count, seed))
    assert len(ps) == count
    for x, y, feature in zip(ps.x_mm, ps.y_mm, ps.features):
        assert on_channel_or_in_face(layout, x, y), (x, y)
        assert feature != "none"


def test_paper_channel_fraction(paper_layout):
    ps = generate_positions(paper_layout, PositionSpec("paper", 200, 1, channel_fraction=1.0))
    assert all(f.startswith("channel:") for f in ps.features)
    ps = generate_positions(paper_layout, PositionSpec("paper", 200, 1, channel_fraction=0.0))
    assert all(f.startswith("face:") for f in ps.features)


@pytest.mark.parametrize("name", sorted(LAYOUTS) + ["paper"])
def test_stratified_covers_every_channel_and_face(name, paper_layout):
    layout = paper_layout if name == "paper" else LAYOUTS[name]
    n_features = len(layout.channels) + len(layout.faces)
    ps = generate_positions(layout, PositionSpec("stratified", n_features, 5))
    expected = {f"channel:{c.name}" for c in layout.channels} | {f"face:{k}" for k in range(len(layout.faces))}
    assert set(ps.features) == expected
    # more positions than features: counts per feature differ by at most one
    ps = generate_positions(layout, PositionSpec("stratified", 2 * n_features + 3, 5))
    counts = Counter(ps.features)
    assert set(counts) == expected and max(counts.values()) - min(counts.values()) <= 1


def test_stratified_small_count_covers_both_kinds(paper_layout):
    ps = generate_positions(paper_layout, PositionSpec("stratified", 6, 7))
    kinds = Counter(f.split(":")[0] for f in ps.features)
    assert kinds == {"channel": 3, "face": 3}
    assert len(set(ps.features)) == 6


def test_grid_strategy(paper_layout):
    ps = generate_positions(paper_layout, PositionSpec("grid", 16, 0))
    assert sorted(set(ps.x_mm)) == [0.0, 10.0, 20.0, 30.0]
    assert sorted(set(ps.y_mm)) == [0.0, 10.0, 20.0, 30.0]
    ps = generate_positions(paper_layout, PositionSpec("grid", 6, 0, grid_shape=(2, 3)))
    assert ps.xy_mm.tolist() == [[0, 0], [15, 0], [30, 0], [0, 30], [15, 30], [30, 30]]
    with pytest.raises(ConfigError, match="grid_shape"):
        PositionSpec("grid", 10, 0)


def test_min_spacing_and_keep_out(paper_layout):
    spec = PositionSpec("paper", 60, 3, min_spacing_mm=2.0, electrode_keep_out_mm=4.0, keep_out=((15.0, 15.0, 3.0),))
    ps = generate_positions(paper_layout, spec)
    xy = ps.xy_mm
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(xy)) * 1e9
    assert d.min() >= 2.0 - 2e-3  # rounding to 1 um
    electrodes = paper_layout.xy_mm[paper_layout.electrode_junctions]
    assert np.linalg.norm(xy[:, None] - electrodes[None], axis=2).min() >= 4.0 - 1e-3
    assert np.hypot(xy[:, 0] - 15, xy[:, 1] - 15).min() >= 3.0 - 1e-3


def test_impossible_spacing_is_a_config_error(paper_layout):
    with pytest.raises(ConfigError, match="min_spacing_mm"):
        generate_positions(paper_layout, PositionSpec("paper", 100, 3, min_spacing_mm=20.0))


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"strategy": "spiral"}, "positions.strategy"),
        ({"count": 0}, "positions.count"),
        ({"seed": -1}, "positions.seed"),
        ({"min_spacing_mm": -1.0}, "positions.min_spacing_mm"),
        ({"channel_fraction": 1.5}, "positions.channel_fraction"),
        ({"keep_out": ((1.0, 2.0),)}, "positions.keep_out[0]"),
    ],
)
def test_bad_spec_fields(kwargs, field):
    with pytest.raises(ConfigError) as info:
        PositionSpec(**({"strategy": "paper", "count": 10} | kwargs))  # the file's required keys, then the bad one
    assert info.value.field == field


L_SHAPE = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 5.0], [5.0, 5.0], [5.0, 20.0], [0.0, 20.0]])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), nx=st.integers(2, 5), ny=st.integers(2, 5))
def test_inside_polygon_agrees_with_matplotlib_on_every_face_and_a_concave_polygon(seed, nx, ny):
    """The even-odd test that replaced matplotlib.path (0.3 s and ~26 MB in the campaign's process) says what it
    says for points off the edges, on the faces of grid skins and on an L shape; a point on an edge may differ
    (the callers treat it as a channel first)."""
    from matplotlib.path import Path as PolygonPath

    from neatskin.gcode.positions import inside_polygon
    from neatskin.skin.layouts import grid_layout

    layout = grid_layout(nx, ny)
    rng = np.random.default_rng(seed)
    polygons = [layout.xy_mm[list(face)] for face in layout.faces] + [L_SHAPE]
    for corners in polygons:
        lo, hi = corners.min(axis=0) - 3.0, corners.max(axis=0) + 3.0
        points = lo + rng.random((2000, 2)) * (hi - lo)
        expected = PolygonPath(corners).contains_points(points)
        assert np.array_equal(inside_polygon(points, corners), expected)
    assert inside_polygon(np.array([[2.0, 2.0], [10.0, 10.0], [2.0, 15.0], [15.0, 2.0]]), L_SHAPE).tolist() == [
        True,
        False,
        True,
        True,
    ]

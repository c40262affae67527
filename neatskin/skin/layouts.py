"""Layouts built in code: square grids of any size (for large-network runs and benchmarks) and
arbitrary graphs on a circle (for solver tests). Files in protocols/skins/ stay the normal way in."""

from __future__ import annotations

import math

from neatskin.layout import Channel, Electrode, Junction, Layout


def grid_layout(
    nx: int,
    ny: int,
    pitch_mm: float = 15.0,
    width_mm: float = 2.0,
    height_mm: float = 1.0,
    electrodes: list[tuple[int, int]] | None = None,
    resistivity_ohm_m: float = 0.5,
    thickness_mm: float = 5.5,
    channel_depth_mm: float = 2.0,
) -> Layout:
    """An nx x ny grid of junctions `pitch_mm` apart with a channel between each pair of neighbours.

    electrodes: grid nodes (i, j) carrying electrodes 1, 2, ...; default the paper's pattern on the
    boundary: bottom middle, then anticlockwise through the corners and edge middles (nodes that
    coincide on small grids count once). grid_layout(3, 3)
    is the paper's skin (same geometry, channel order may differ from protocols/skins/paper.toml).
    """
    if nx < 2 or ny < 2:
        raise ValueError(f"a grid needs at least 2 x 2 junctions, got {nx} x {ny}")
    idx: dict[tuple[int, ...], int] = {(i, j): j * nx + i for j in range(ny) for i in range(nx)}
    junctions = tuple(Junction(f"J{i}_{j}", i * pitch_mm, j * pitch_mm) for j in range(ny) for i in range(nx))
    channels = []
    for j in range(ny):
        for i in range(nx):
            if i + 1 < nx:
                channels.append(Channel(f"h{i}_{j}", idx[i, j], idx[i + 1, j], pitch_mm, width_mm, height_mm))
            if j + 1 < ny:
                channels.append(Channel(f"v{i}_{j}", idx[i, j], idx[i, j + 1], pitch_mm, width_mm, height_mm))
    if electrodes is None:
        mx, my = (nx - 1) // 2, (ny - 1) // 2
        electrodes = [(mx, 0), (nx - 1, 0), (nx - 1, my), (nx - 1, ny - 1), (mx, ny - 1), (0, ny - 1), (0, my), (0, 0)]
        electrodes = list(dict.fromkeys(electrodes))  # small grids: middles coincide with corners
    if len(set(map(tuple, electrodes))) != len(electrodes):
        raise ValueError(f"two electrodes on the same grid node: {electrodes}")
    elec = tuple(Electrode(k + 1, idx[tuple(e)]) for k, e in enumerate(electrodes))
    return Layout(
        f"grid-{nx}x{ny}",
        junctions,
        tuple(channels),
        elec,
        resistivity_ohm_m=resistivity_ohm_m,
        thickness_mm=thickness_mm,
        channel_depth_mm=channel_depth_mm,
        source=f"<grid_layout {nx}x{ny}>",
    )


def graph_layout(
    n_junctions: int,
    edges: list[tuple[int, int]],
    electrode_junctions: list[int],
    radius_mm: float = 10.0,
    name: str = "graph",
) -> Layout:
    """Junctions evenly on a circle, a unit channel (1 mm long, 1 mm x 1 mm, rho = 1 ohm m) per edge,
    electrodes 1, 2, ... on the given junctions. For solver tests on arbitrary connected graphs."""
    junctions = tuple(
        Junction(
            f"J{k}",
            radius_mm * math.cos(2 * math.pi * k / n_junctions),
            radius_mm * math.sin(2 * math.pi * k / n_junctions),
        )
        for k in range(n_junctions)
    )
    channels = tuple(Channel(f"C{a}-{b}", a, b, 1.0, 1.0, 1.0) for a, b in edges)
    electrodes = tuple(Electrode(k + 1, j) for k, j in enumerate(electrode_junctions))
    return Layout(
        name,
        junctions,
        channels,
        electrodes,
        resistivity_ohm_m=1.0,
        thickness_mm=5.0,
        channel_depth_mm=2.0,
        source=f"<graph_layout {name}>",
    )

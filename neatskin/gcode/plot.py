"""A press-position map as PNG: the layout's channels, faces and electrodes, the positions by feature, the route.

Lets a technician see the positions (and the travel order) before a campaign starts.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from neatskin.gcode.positions import PositionSet
from neatskin.layout import Layout


def plot_positions(
    layout: Layout,
    positions: PositionSet,
    path: str | Path,
    *,
    title: str = "",
    route: np.ndarray | Sequence[int] | None = None,
    probe_diameter_mm: float | None = None,
) -> Path:
    """Write the map to `path` (PNG); `route` is an order of position ids to draw as the travel path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=120)
    for k, face in enumerate(layout.faces):
        pts = layout.xy_mm[list(face)]
        ax.add_patch(Polygon(pts, closed=True, facecolor="#eef3fb", edgecolor="none", zorder=0))
        cx, cy = pts.mean(axis=0)
        ax.text(float(cx), float(cy), f"face {k}", ha="center", va="center", fontsize=7, color="#8899bb", zorder=1)
    for ch in layout.channels:
        (ax_, ay), (bx, by) = layout.xy_mm[ch.a], layout.xy_mm[ch.b]
        ax.plot([ax_, bx], [ay, by], color="#9fc5e8", linewidth=ch.width_mm * 4, solid_capstyle="round", zorder=1)
    for e in layout.electrodes:
        x, y = layout.xy_mm[e.junction]
        ax.plot(x, y, "s", color="#444444", markersize=7, zorder=3)
        ax.annotate(str(e.number), (x, y), textcoords="offset points", xytext=(6, 6), fontsize=8, zorder=4)
    xy = positions.xy_mm
    on_channel = np.array([f.startswith("channel:") for f in positions.features], dtype=bool)
    if route is not None and len(route) > 1:
        r = xy[np.asarray(route)]
        ax.plot(r[:, 0], r[:, 1], "-", color="#bbbbbb", linewidth=0.7, zorder=2, label="travel route")
    ax.plot(
        xy[on_channel, 0],
        xy[on_channel, 1],
        "o",
        color="#d62728",
        markersize=4,
        zorder=5,
        label=f"on a channel ({int(on_channel.sum())})",
    )
    ax.plot(
        xy[~on_channel, 0],
        xy[~on_channel, 1],
        "o",
        color="#1f77b4",
        markersize=4,
        zorder=5,
        label=f"in a face ({int((~on_channel).sum())})",
    )
    if probe_diameter_mm and len(xy):
        ax.add_patch(
            Circle(
                xy[0],
                probe_diameter_mm / 2,
                fill=False,
                linestyle="--",
                color="#555555",
                zorder=6,
                label=f"probe footprint ({probe_diameter_mm:g} mm)",
            )
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm, sensor frame)")
    ax.set_ylabel("y (mm, sensor frame)")
    ax.set_title(title or f"{len(positions)} press positions on {layout.name}")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path

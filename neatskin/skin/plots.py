"""Sensitivity-map figures as PNG (paper Fig. 3 and Fig. 5 style): normalised dR_eq, its colour bar 0..1 when no
value is negative (a press only raises dR_eq) and -1..1 otherwise, channel boundaries dashed, electrodes numbered.
Matplotlib with the Agg backend; no screen needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neatskin.layout import ElectrodePair, Layout
from neatskin.skin.maps import SensitivityMap

_CMAP = "RdBu_r"  # diverging: for maps with negative values
_CMAP_POSITIVE = "Reds"  # the same reds, from white at 0: for maps that are all >= 0


def colour_scale(values: np.ndarray) -> tuple[str, float, float]:
    """(colour map, vmin, vmax) fitted to the normalised values: 0..1 unless one of them is negative."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size and finite.min() < 0:
        return _CMAP, -1.0, 1.0
    return _CMAP_POSITIVE, 0.0, 1.0


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_layout(ax, layout: Layout) -> None:
    """Channel walls as dashed lines (each channel's two sides, width apart), electrode numbers."""
    xy = layout.xy_mm
    for ch in layout.channels:
        a, b = xy[ch.a], xy[ch.b]
        unit = (b - a) / np.hypot(*(b - a))
        normal = np.array([-unit[1], unit[0]]) * ch.width_mm / 2
        for side in (normal, -normal):
            ax.plot([a[0] + side[0], b[0] + side[0]], [a[1] + side[1], b[1] + side[1]], ls="--", lw=0.8, color="k")
    for e in layout.electrodes:
        jx, jy = xy[e.junction]
        ax.annotate(
            str(e.number),
            (jx, jy),
            xytext=(0, 0),
            textcoords="offset points",
            ha="center",
            va="center",
            fontsize=8,
            fontweight="bold",
            bbox=dict(boxstyle="circle,pad=0.2", fc="gold", ec="k", lw=0.6),
        )


def _field_on_grid(layout: Layout, smap: SensitivityMap, values: np.ndarray, step_mm: float):
    """Values on a regular grid: the map's own grid if it is one, else interpolated from its points."""
    xs, ys = np.unique(smap.x_mm), np.unique(smap.y_mm)
    if xs.size * ys.size == smap.x_mm.size and xs.size > 3:
        order = np.lexsort((smap.x_mm, smap.y_mm))
        return xs, ys, values[order].reshape(ys.size, xs.size)
    from scipy.interpolate import griddata

    x0, y0, x1, y1 = layout.bounds_mm
    gx, gy = np.meshgrid(np.arange(x0, x1 + step_mm / 2, step_mm), np.arange(y0, y1 + step_mm / 2, step_mm))
    pts = np.column_stack([smap.x_mm, smap.y_mm])
    field = griddata(pts, values, (gx, gy), method="linear")
    nearest = griddata(pts, values, (gx, gy), method="nearest")
    field = np.where(np.isnan(field), nearest, field)
    return gx[0], gy[:, 0], field


def _panel(ax, layout: Layout, smap: SensitivityMap, values: np.ndarray, title: str, step_mm: float, scale):
    xs, ys, field = _field_on_grid(layout, smap, values, step_mm)
    cmap, vmin, vmax = scale
    mesh = ax.pcolormesh(xs, ys, field, cmap=cmap, vmin=vmin, vmax=vmax, shading="nearest")
    if smap.x_mm.size < 200:  # the paper's simulated presses: black dots
        ax.plot(smap.x_mm, smap.y_mm, "k.", ms=5)
    draw_layout(ax, layout)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    return mesh


def plot_z(layout: Layout, smap: SensitivityMap, path: str | Path, title: str, step_mm: float = 0.25) -> Path:
    """One map of z (paper eq. 2, Fig. 3) to a PNG file."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.4, 4.6), dpi=120, layout="constrained")
    mesh = _panel(ax, layout, smap, smap.z, title, step_mm, colour_scale(smap.z))
    fig.colorbar(mesh, ax=ax, label="normalised max dR_eq over S")
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_pairs(
    layout: Layout,
    smap: SensitivityMap,
    pairs: tuple[ElectrodePair, ...],
    path: str | Path,
    title: str,
    step_mm: float = 0.25,
) -> Path:
    """One panel per pair (paper Fig. 5: the symmetry class representatives), each normalised to [-1, 1]."""
    plt = _pyplot()
    cols = min(3, len(pairs))
    rows = -(-len(pairs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.3 * rows), dpi=110, squeeze=False, layout="constrained")
    mesh = None
    values = [smap.pair_normalised(pair) for pair in pairs]
    scale = colour_scale(np.concatenate(values)) if values else colour_scale(np.zeros(1))  # one bar for all panels
    for ax, pair, v in zip(axes.flat, pairs, values):
        mesh = _panel(ax, layout, smap, v, f"pair {pair}", step_mm, scale)
    for ax in list(axes.flat)[len(pairs) :]:
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.colorbar(mesh, ax=axes, shrink=0.8, label="normalised dR_eq")
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


# issue 22's independent estimate (quasi-3D FE), A/A0 of the channel: at 3.5 mm deep against the horizontal distance
# from the probe axis, and under the probe against depth (below 0.05 from 1 mm: drawn as an upper bound)
ESTIMATE_AT_3P5_MM = ((4.0, 0.14), (5.0, 0.72), (6.0, 0.92), (7.5, 1.0))
ESTIMATE_UNDER_PROBE = ((0.5, 0.56),)
ESTIMATE_UNDER_PROBE_BELOW = ((1.0, 0.05),)
ESTIMATE_FORCE_3P5_MM_N = 3.5


def plot_kernel(kernel, path: Path, title: str) -> Path:
    """The pinch kernel: A/A0 against the distance from the probe axis (a few depths) and against depth (a few
    distances), the quasi-3D kernel (solid, its transfer spread shaded) beside the plane-strain strip (dashed) and
    the independent estimate of issue 22 (black); and the probe force against depth."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.6))
    cmap = plt.get_cmap("viridis")
    extra = kernel.extra or {}
    strip, spread = extra.get("area_ratio_plane_strain"), extra.get("area_ratio_spread")
    depths = [d for d in (0.5, 1.0, 2.0, 3.5) if d <= kernel.depths_mm[-1] + 1e-9]
    for k, d in enumerate(depths):
        j, color = int(np.argmin(np.abs(kernel.depths_mm - d))), cmap(k / max(len(depths) - 1, 1))
        a = kernel.area_ratio[:, j]
        axes[0].plot(kernel.offsets_mm, a, "o-", ms=3, color=color, label=f"{d:g} mm, quasi-3D")
        if spread is not None:
            lo, hi = np.clip(a - spread[:, j], 0, 1), np.clip(a + spread[:, j], 0, 1)
            axes[0].fill_between(kernel.offsets_mm, lo, hi, color=color, alpha=0.12, lw=0)
        if strip is not None:
            axes[0].plot(kernel.offsets_mm, strip[:, j], "--", color=color, lw=1, label=f"{d:g} mm, plane strain")
    ex, ey = zip(*ESTIMATE_AT_3P5_MM, strict=True)
    axes[0].plot(ex, ey, "k*", ms=11, label="independent estimate, 3.5 mm")
    axes[0].set(xlabel="distance from the probe axis (mm)", ylabel="A / A0", title="channel area against distance")
    axes[0].legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.14))
    offsets = [o for o in (0.0, 3.0, 4.0, 5.0, 6.0, 7.5, 10.0) if o <= kernel.offsets_mm[-1]]
    for k, o in enumerate(offsets):
        i, color = int(np.argmin(np.abs(kernel.offsets_mm - o))), cmap(k / max(len(offsets) - 1, 1))
        axes[1].plot(kernel.depths_mm, kernel.area_ratio[i], "o-", ms=3, color=color, label=f"{o:g} mm")
        if strip is not None:
            axes[1].plot(kernel.depths_mm, strip[i], "--", color=color, lw=1)
    for (d, a), marker in ((ESTIMATE_UNDER_PROBE[0], "k*"), (ESTIMATE_UNDER_PROBE_BELOW[0], "kv")):
        axes[1].plot([d], [a], marker, ms=10)
    axes[1].set(
        xlabel="press depth (mm)",
        ylabel="A / A0",
        title="against depth (dashed: plane strain; black: estimate under the probe)",
    )
    axes[1].legend(title="distance", fontsize=7)
    for ax in axes[:2]:
        ax.axhline(0.02, color="grey", lw=0.8, ls=":")
        ax.set_ylim(-0.03, 1.05)
        ax.grid(alpha=0.3)
    for o in offsets[:1] + offsets[-1:]:
        i = int(np.argmin(np.abs(kernel.offsets_mm - o)))
        axes[2].plot(kernel.depths_mm, kernel.force_n[i], "o-", ms=3, label=f"strip over the chords, {o:g} mm")
    if "force_axisymmetric_n" in extra:
        axes[2].plot(kernel.depths_mm, extra["force_axisymmetric_n"][0], "s-", ms=3, label="round probe, intact (3D)")
    axes[2].plot([3.5], [ESTIMATE_FORCE_3P5_MM_N], "k*", ms=11, label="independent estimate")
    axes[2].set(xlabel="press depth (mm)", ylabel="probe force (N)", title="probe force")
    axes[2].legend(fontsize=7)
    axes[2].grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

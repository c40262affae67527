"""Dataset plots as PNG (matplotlib, Agg backend): the experimental sensitivity map (paper Fig. 8) and the
map of pressed positions. The map values are computed by pure functions; drawing is the only I/O.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from neatskin.datasets.manifest import read_manifest, resolve_manifest_path
from neatskin.datasets.paths import MANIFEST_NAME
from neatskin.datasets.reader import pair_labels_from_columns, read_presses
from neatskin.datasets.scan import cut_pairs_only
from neatskin.errors import DataError
from neatskin.layout import Layout, load_layout

FIGSIZE_IN = (6.0, 5.0)
DPI = 100  # 600 x 500 px


def sensitivity_by_position(df: pd.DataFrame) -> pd.DataFrame:
    """Per position: x_mm, y_mm, presses, cut_presses, and z = max over pairs of the mean dR over its repeats,
    normalised to [-1, 1] by the largest |z| over the presses that cut no pair (paper eq. 2 on measured data).

    A press that cut a pair off (a channel pinched shut: that pair's dR = +inf, its row flagged `open_circuit:i-j`
    and nothing else) is the most sensitive reading there is, so it counts: its position's z is +inf (drawn at the
    top of the bar, marked), `cut_presses` says how many, and the finite values of the other positions do not move.
    Presses flagged for anything else (a missed sweep, a pair clipped but still conducting) are left out."""
    flags = df["flags"].tolist()
    flagged = np.array([len(f) > 0 for f in flags], dtype=bool)
    cut = cut_pairs_only(pa.chunked_array([pa.array(flags, type=pa.list_(pa.string()))]), flagged)
    used = df[~flagged | cut].assign(cut_press=cut[~flagged | cut])
    pairs = pair_labels_from_columns(used)
    dr_cols = [f"dR_ohm_{p.i}_{p.j}" for p in pairs]
    grouped = used.groupby("position_id")
    with np.errstate(invalid="ignore"):  # +inf and -inf (a cut baseline) in one pair's repeats: NaN, masked below
        mean_dr = grouped[dr_cols].mean()
    # a pair cut in any repeat: its mean is +inf, the position's max with it (also where another repeat's cut
    # baseline left -inf, whose mean with +inf would be NaN and skipped)
    mean_dr = mean_dr.mask((used[dr_cols] == np.inf).groupby(used["position_id"]).any(), np.inf)
    out = grouped[["x_mm", "y_mm"]].first()
    out["presses"] = grouped.size()
    out["cut_presses"] = grouped["cut_press"].sum().astype(int)
    z = mean_dr.max(axis=1).to_numpy(float)
    # the scale: the largest |z| over the presses that cut nothing, as before cut presses were drawn, so a position's
    # cut press moves no other position's value (a cut position's own clean presses still count towards it)
    clean = used[~used["cut_press"]]
    clean_dr = clean.groupby("position_id")[dr_cols].mean()
    clean_z = clean_dr.where(np.isfinite(clean_dr)).max(axis=1).to_numpy(float)
    scale = np.max(np.abs(clean_z[np.isfinite(clean_z)])) if np.isfinite(clean_z).any() else 0.0
    out["z"] = z / scale if scale > 0 else z
    out["best_pair"] = mean_dr.idxmax(axis=1).astype(str).str.removeprefix("dR_ohm_").str.replace("_", "-")
    return out.reset_index()


def sensitivity_title(df: pd.DataFrame, sens: pd.DataFrame) -> str:
    """The map's title: the positions and presses it was drawn from, the presses that cut a pair off (drawn, at the
    top), and what it left out. (It said every press of the campaign: '92 positions, 2800 presses' for a paper dry
    run whose map then left out the 498 presses that cut a pair off, and with them 8 positions.)"""
    used = int(sens["presses"].sum()) if len(sens) else 0
    title = f"Sensitivity (paper Fig. 8): max over pairs of mean dR\n{len(sens)} positions, {used} presses"
    cut = int(sens["cut_presses"].sum()) if len(sens) else 0
    if cut:
        at = int((sens["cut_presses"] > 0).sum())
        title += (
            f"\n{cut} press{'es' if cut != 1 else ''} cut a pair off (dR = inf): "
            f"{at} position{'s' if at != 1 else ''} at the top, marked x"
        )
    left = len(df) - used
    if left:
        gone = df["position_id"].nunique() - len(sens)
        title += f"\n{left} otherwise flagged press{'es' if left != 1 else ''} left out"
        if gone:
            title += f" ({gone} position{'s' if gone != 1 else ''} wholly)"
    return title


def layout_for(path: str | os.PathLike, layout: Layout | str | os.PathLike | None = None) -> Layout:
    """The layout given, else the one the campaign's manifest names, else (a press file outside a campaign folder)
    the one its metadata names, found beside it and checked against its recorded sha256."""
    if isinstance(layout, Layout):
        return layout
    if layout is not None:
        return load_layout(Path(layout))
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    if path.is_file() and not (folder / MANIFEST_NAME).is_file():
        from neatskin.datasets.reader import read_metadata
        from neatskin.datasets.values import metadata_layout

        found = metadata_layout(folder, read_metadata(path), None)
        if found is None:
            raise DataError(
                "a press file outside its campaign folder, and the layout its metadata names is not beside it",
                file=str(path),
                field="layout",
                fix="pass --layout protocols/skins/<skin>.toml, or plot the campaign folder",
            )
        return found
    manifest = read_manifest(folder)
    layout_path = resolve_manifest_path(folder, manifest, "layout")
    if layout_path is None:
        raise DataError(
            "the manifest names no layout",
            file=str(folder / MANIFEST_NAME),
            field="layout",
            fix="pass --layout protocols/skins/<skin>.toml",
        )
    return load_layout(layout_path)


def _draw_channels(ax, layout: Layout) -> None:
    """Each channel's two long boundaries, dashed (as in the paper's figures)."""
    for ch in layout.channels:
        a, b = layout.xy_mm[ch.a], layout.xy_mm[ch.b]
        direction = (b - a) / np.linalg.norm(b - a)
        normal = np.array([-direction[1], direction[0]]) * ch.width_mm / 2
        for side in (normal, -normal):
            ax.plot(
                [a[0] + side[0], b[0] + side[0]],
                [a[1] + side[1], b[1] + side[1]],
                linestyle="--",
                color="black",
                linewidth=0.8,
            )


def _figure():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")  # title and bar kept apart
    return plt, fig, ax


def _finish(plt, fig, ax, layout: Layout, out: Path, title: str) -> Path:
    x0, y0, x1, y1 = layout.bounds_mm
    margin = 0.08 * max(x1 - x0, y1 - y0)
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim(y0 - margin, y1 + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def plot_sensitivity_map(
    path: str | os.PathLike,
    out: str | os.PathLike,
    layout: Layout | str | os.PathLike | None = None,
    grid_step_mm: float = 0.25,
) -> Path:
    """Paper Fig. 8: normalised max-over-pairs mean dR per pressed position, interpolated linearly between
    positions (blank outside their convex hull), pressed positions as dots, channel boundaries dashed. A position
    where a press cut a pair off is drawn at the top of the bar (its arrow) and marked with a red x."""
    from scipy.interpolate import griddata

    df = read_presses(path)  # first: a path that holds no presses is told as such, not as a missing manifest
    layout = layout_for(path, layout)
    sens = sensitivity_by_position(df)
    plt, fig, ax = _figure()
    x0, y0, x1, y1 = layout.bounds_mm
    gx, gy = np.meshgrid(
        np.arange(x0, x1 + grid_step_mm / 2, grid_step_mm), np.arange(y0, y1 + grid_step_mm / 2, grid_step_mm)
    )
    points = sens[["x_mm", "y_mm"]].to_numpy(float)
    z = sens["z"].to_numpy(float)
    vmin, vmax = colour_range(z)
    cut = z == np.inf
    z = np.where(cut, vmax, z)  # a cut pair: saturated at the top of the bar (and marked below), never dropped
    ok = np.isfinite(z)
    if ok.sum() >= 3 and np.linalg.matrix_rank(points[ok] - points[ok].mean(axis=0)) == 2:
        grid = griddata(points[ok], z[ok], (gx, gy), method="linear")
        image = ax.pcolormesh(gx, gy, grid, cmap="viridis", vmin=vmin, vmax=vmax, shading="auto")
    else:
        image = ax.scatter(points[:, 0], points[:, 1], c=z, cmap="viridis", vmin=vmin, vmax=vmax, s=60)
    fig.colorbar(image, ax=ax, label="normalised max dR (Fig. 8)", extend="max" if cut.any() else "neither")
    ax.scatter(points[~cut, 0], points[~cut, 1], s=6, color="black")
    if cut.any():
        # no legend: it would hide pressed positions in a corner; the title says what the red x is
        ax.scatter(points[cut, 0], points[cut, 1], s=40, marker="x", color="red", linewidths=1.5, zorder=3)
    _draw_channels(ax, layout)
    return _finish(
        plt,
        fig,
        ax,
        layout,
        Path(out),
        sensitivity_title(df, sens),
    )


def colour_range(z: np.ndarray) -> tuple[float, float]:
    """The normalised map's colour range: 0..1 when no value is negative (a press raises dR: the usual case),
    -1..1 when one is, so the bar spans the data and no more. A cut pair's +inf is at the top of either."""
    finite = z[np.isfinite(z)]
    return (0.0, 1.0) if finite.size == 0 or finite.min() >= 0 else (-1.0, 1.0)


def plot_press_map(
    path: str | os.PathLike, out: str | os.PathLike, layout: Layout | str | os.PathLike | None = None
) -> Path:
    """The pressed positions, numbered by position_id and coloured by how many presses each received."""
    df = read_presses(path)  # first: a path that holds no presses is told as such, not as a missing manifest
    layout = layout_for(path, layout)
    per = df.groupby("position_id").agg(x_mm=("x_mm", "first"), y_mm=("y_mm", "first"), presses=("press_id", "size"))
    plt, fig, ax = _figure()
    _draw_channels(ax, layout)
    counts = per["presses"].to_numpy(int)
    if counts.size and counts.min() == counts.max():  # every position pressed alike: one colour, no bar to read
        ax.scatter(per["x_mm"], per["y_mm"], color="tab:purple", s=40, edgecolors="black", linewidths=0.5, zorder=3)
        repeats = f"{counts[0]} presses at every position"
    else:
        from matplotlib.colors import BoundaryNorm

        levels = np.arange(counts.min(), counts.max() + 2) - 0.5  # one colour per whole count
        image = ax.scatter(
            per["x_mm"],
            per["y_mm"],
            c=counts,
            cmap="plasma",
            norm=BoundaryNorm(levels, 256),
            s=40,
            edgecolors="black",
            linewidths=0.5,
            zorder=3,
        )
        from matplotlib.ticker import MaxNLocator

        bar = fig.colorbar(image, ax=ax, label="presses (repeats) at the position")
        bar.locator = MaxNLocator(integer=True)
        bar.update_ticks()
        repeats = f"{counts.min()} to {counts.max()} presses per position"
    for position_id, row in per.iterrows():
        ax.annotate(
            str(position_id),
            (row["x_mm"], row["y_mm"]),
            xytext=(3, 3),
            textcoords="offset points",
            fontsize=6,
            zorder=4,
        )
    return _finish(
        plt, fig, ax, layout, Path(out), f"Pressed positions: {len(per)} positions, {len(df)} presses\n({repeats})"
    )

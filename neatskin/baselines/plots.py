"""Report figures: error against compute time per split (linear error, log time) with the physical floors,
per-position error ellipses as paper Fig. 9, and the physical limit's bound map."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from neatskin.baselines.evaluate import ModelResult
from neatskin.baselines.metrics import PROBE_RADIUS_MM, error_ellipses

PAPER_READINGS = {"random": "its stated 95/3/2 split", "design": "its scored 11 x 6 test"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


FLOOR_COLUMNS = (  # physical_limit.parquet columns drawn as floors, in this order, with their honest names
    ("crb_mm", "Cramér-Rao bound, electronics only", "black", "-."),
    ("crb_nuisance_mm", "Cramér-Rao bound with depth, drift, placement (nuisance floor)", "tab:purple", "--"),
    ("label_noise_floor_mm", "label-noise floor (landing point vs commanded)", "tab:brown", ":"),
    ("label_noise_floor", "label-noise floor (landing point vs commanded)", "tab:brown", ":"),
)
OFF_VIEW_FACTOR = 3.0  # a model whose mean error is this many times the (lower) median model's sits on the top edge


def _split_label_floor_mm(table, split: str) -> float | None:
    """The label-noise floor (mean) of the split, as the report's table gives it per row (`label_floor_mean_mm`)."""
    if table is None or "label_floor_mean_mm" not in table.columns:
        return None
    values = table.loc[table["split"] == split, "label_floor_mean_mm"].to_numpy(dtype=float)
    values = values[np.isfinite(values)]
    return float(values[0]) if values.size else None


def floors_mm(limit, extent_mm: float = np.inf) -> dict[str, tuple[float, str, str]]:
    """The pooled floors (sqrt of the mean square over positions) the physical limit gives: name -> (mm, colour,
    line style). A column absent from the file (an older dataset, a floor not computed) is left out, and so is a
    Cramér-Rao bound that exceeds the skin (extent_mm) at some position: the report compares no error with it
    (`floortext.comparable`), and its pooled value, held by those positions, would only stretch the axis."""
    floors: dict[str, tuple[float, str, str]] = {}
    if limit is None or len(limit) == 0:
        return floors
    for column, name, colour, style in FLOOR_COLUMNS:
        if column in limit.columns and name not in floors:
            values = limit[column].to_numpy(dtype=float)
            if column.startswith("crb") and not np.all(values <= extent_mm):
                continue
            floors[name] = (float(np.sqrt(np.mean(values * values))), colour, style)
    return floors


def plot_error_vs_time(
    results: list[ModelResult],
    path: Path,
    bound_rms_mm: float | None = None,
    table=None,
    floors: Mapping[str, tuple[float, str, str]] | None = None,
) -> Path:
    """`error_vs_time_figure` saved as a PNG."""
    plt = _pyplot()
    fig = error_vs_time_figure(results, bound_rms_mm, table, floors)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def error_vs_time_figure(
    results: list[ModelResult],
    bound_rms_mm: float | None = None,
    table=None,
    floors: Mapping[str, tuple[float, str, str]] | None = None,
):
    """Mean error over repeats (bars: 95 % interval of the mean) against time per fit + predict, one panel per split.

    The error axis is linear and spans the models' errors (from 0): the bars are what a reader compares, and on
    a log axis reaching down to the electronics-only bound they shrank to a sliver. Time stays logarithmic
    (fits span decades). The floors the physical limit gives (`floors_mm`) are horizontal lines under their
    names; a floor far below the models sits on the axis floor and keeps its value in the legend. A model
    more than OFF_VIEW_FACTOR times the median model's error is drawn as a triangle on the top edge with its
    value; a result flagged as memorisation (the table's `below_bound`) is a black triangle at its value.
    The paper's 2.03 mm appears on the random and the design split's panels, the two readings of its test set (a
    95/3/2 split stated, 11 positions x 6 presses scored), not on the grouped one.
    """
    plt = _pyplot()
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    if floors is None:
        floors = {}
        if bound_rms_mm is not None and np.isfinite(bound_rms_mm) and bound_rms_mm > 0:
            floors = {FLOOR_COLUMNS[0][1]: (float(bound_rms_mm), FLOOR_COLUMNS[0][2], FLOOR_COLUMNS[0][3])}
    floors = {k: v for k, v in floors.items() if np.isfinite(v[0]) and v[0] > 0}
    splits = list(dict.fromkeys(r.split for r in results))
    models = list(dict.fromkeys(r.model for r in results))
    colours = {m: f"C{i % 10}" for i, m in enumerate(models)}
    fig, axes = plt.subplots(1, len(splits), figsize=(max(5.0 * len(splits), 9.0), 5.2), squeeze=False, sharey=True)

    flagged = set()
    if table is not None and "below_bound" in table.columns:  # the report's one rule (resultstable.results_table)
        flagged = {(m, sp) for m, sp, b in zip(table["model"], table["split"], table["below_bound"]) if b}

    def memorised(r: ModelResult) -> bool:
        return (r.model, r.split) in flagged

    honest = [r for r in results if not memorised(r)]
    means = np.array([r.summary["mean_error_mm"].mean for r in honest], dtype=float)
    means = means[np.isfinite(means)]
    cap = OFF_VIEW_FACTOR * float(np.sort(means)[(means.size - 1) // 2]) if means.size else 1.0
    in_view = [r for r in honest if r.summary["mean_error_mm"].mean <= cap]
    top_values = [r.summary["mean_error_mm"].high for r in in_view] + [v for v, _, _ in floors.values()]
    top_values += [PROBE_RADIUS_MM] + ([2.03] if "random" in splits else [])
    top = 1.1 * max(v for v in top_values if np.isfinite(v))
    for ax, split in zip(axes[0], splits):
        memorisers: list[str] = []
        for r in (r for r in results if r.split == split):
            s = r.summary["mean_error_mm"]
            seconds = max(r.fit_time_s + r.predict_time_per_sample_s * r.per_repeat[0].n, 1e-5)
            if memorised(r):
                ax.plot(seconds, max(s.mean, 0.0), "v", color="black", ms=9, label="memorisation: below the bound")
                memorisers.append(r.model)
                continue
            if s.mean > top:  # an extrapolating model: its value on the top edge, not a squeezed axis
                ax.plot(seconds, top, "^", color=colours[r.model], ms=9, label=r.model, clip_on=False)
                ax.annotate(
                    f"{s.mean:.3g} mm",
                    (seconds, top),
                    xytext=(0, -12),
                    textcoords="offset points",
                    fontsize=7,
                    ha="center",
                    color=colours[r.model],
                )
                continue
            ax.errorbar(
                seconds,
                s.mean,
                yerr=[[s.mean - max(s.low, 0.0)], [s.high - s.mean]],
                color=colours[r.model],
                fmt="o",
                ms=6,
                capsize=4,
                elinewidth=1.5,
                label=r.model,
            )
        ax.axhline(PROBE_RADIUS_MM, color="grey", ls=":", lw=1, label=f"probe radius {PROBE_RADIUS_MM} mm")
        if split in PAPER_READINGS:  # the paper's stated split and its scored 11 x 6 test (report.md says which)
            ax.axhline(
                2.03, color="tab:red", ls="--", lw=1, label=f"paper, real skin, {PAPER_READINGS[split]}: 2.03 mm"
            )
        for name, (value, colour, style) in floors.items():
            ax.axhline(min(value, top), color=colour, ls=style, lw=1.2, label=f"{name}: {value:.3g} mm")
        label_floor = _split_label_floor_mm(table, split)
        if label_floor is not None:
            ax.axhline(
                label_floor,
                color="tab:brown",
                ls=":",
                lw=1.5,
                label=f"label-noise floor, {split}: {label_floor:.3g} mm",
            )
        ax.set_xscale("log")
        # ticks at 1, 2, 5 per decade labelled plainly (0.02, 0.05, 0.1): readable within one decade, no collisions
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_ylim(0.0, top)
        ax.set_xlabel("time per fit + predicting the test rows (s, log)")
        # memorisers named in the title: labels beside each triangle would collide with each other
        note = f"\n▼ memorise (below the bound): {', '.join(memorisers)}" if memorisers else ""
        ax.set_title(f"{split} split{note}", fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    axes[0][0].set_ylabel("mean Euclidean error (mm)\nbars: 95 % interval of the mean over repeats")
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    ncol = 4
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=min(ncol, len(labels)))
    fig.suptitle("Position error against compute time (one marker per model; mean over repeated splits)", fontsize=10)
    rows = 1 + (len(labels) - 1) // ncol
    fig.tight_layout(rect=(0, 0.045 * rows + 0.01, 1, 1))
    return fig


def _draw_layout(ax, layout) -> None:
    if layout is None:
        return
    xy = layout.xy_mm
    for a, b in layout.channel_ends:
        ax.plot(xy[[a, b], 0], xy[[a, b], 1], color="grey", ls="--", lw=0.8)


def plot_error_ellipses(
    results: list[ModelResult], path: Path, layout=None, max_positions: int | None = None, seed: int = 0
) -> Path:
    """One panel per model: probe circles at true positions, mean predictions, 1-std ellipses, error lines.

    Each panel's shapes are drawn as one collection per kind (circles, ellipses, lines), not one
    artist per position: the same picture, drawn in a fraction of the time."""
    from matplotlib.collections import LineCollection, PatchCollection
    from matplotlib.patches import Circle, Ellipse

    plt = _pyplot()
    n = len(results)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.2 * rows), squeeze=False)
    for ax, r in zip(axes.ravel(), results):
        ell = error_ellipses(r.y_true_mm, r.y_pred_mm, r.groups)
        keep = np.arange(len(ell.group))
        if max_positions is not None and len(keep) > max_positions:
            keep = np.sort(np.random.default_rng(seed).choice(keep, max_positions, replace=False))
        _draw_layout(ax, layout)
        true_mm, mean_mm = ell.true_mm[keep], ell.mean_pred_mm[keep]
        hit = ell.centre_error_mm[keep] <= PROBE_RADIUS_MM
        circles = [Circle(t, PROBE_RADIUS_MM) for t in true_mm]
        ax.add_collection(PatchCollection(circles, facecolor="none", edgecolor="tab:blue", linewidth=0.6))
        ellipses = [
            Ellipse(m, 2 * a[0], 2 * a[1], angle=np.degrees(angle))
            for m, a, angle in zip(mean_mm, ell.std_axes_mm[keep], ell.angle_rad[keep])
        ]
        ax.add_collection(PatchCollection(ellipses, color="tab:green", alpha=0.45))
        segments = np.stack([true_mm, mean_mm], axis=1)
        ax.add_collection(
            LineCollection(list(segments), colors=np.where(hit, "black", "tab:red").tolist(), linewidths=0.8)
        )
        ax.plot(mean_mm[:, 0], mean_mm[:, 1], ".", color="tab:green", ms=3)
        ax.set_aspect("equal")
        # one view for every panel: the pressed area and a probe diameter around it, so panels compare;
        # a mean prediction that lands outside is drawn to the edge and counted in the title
        lo = ell.true_mm.min(axis=0) - 2 * PROBE_RADIUS_MM
        hi = ell.true_mm.max(axis=0) + 2 * PROBE_RADIUS_MM
        if layout is not None:  # the whole skin outline too: a design away from an edge cropped it at x = 0
            x0, y0, x1, y1 = layout.bounds_mm
            lo = np.minimum(lo, np.array([x0, y0]) - 1.0)
            hi = np.maximum(hi, np.array([x1, y1]) + 1.0)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        outside = int(np.sum(np.any((ell.mean_pred_mm[keep] < lo) | (ell.mean_pred_mm[keep] > hi), axis=1)))
        note = f", {outside} mean(s) off the view" if outside else ""
        which = "first k-fold partition" if r.split == "grouped" else "repeat 0"
        ax.set_title(f"{r.model} ({r.split}, {which})\n{r.errors.mean_error_mm:.2f} mm{note}", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(
        "Per position: probe radius at the true position (blue), mean prediction (green dot) with its 1-std "
        "ellipse (green);\nline from truth to mean: black inside the probe radius, red outside",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _panel_norm(values: np.ndarray):
    """A colour scale fitted to one panel's finite positive values: logarithmic when they span more than a
    decade, else linear (a bound that is nearly constant over the skin reads as one colour, not as noise)."""
    from matplotlib.colors import LogNorm, Normalize

    finite = values[np.isfinite(values) & (values > 0)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (1e-3, 1.0)
    if hi > 10.0 * lo:
        return LogNorm(vmin=lo, vmax=hi), " (log)"
    if hi <= lo * 1.001:  # one value: a band of +-10 % around it, so the bar still reads
        lo, hi = lo * 0.9, hi * 1.1
    return Normalize(vmin=lo, vmax=hi), ""


def plot_bound_map(limit, path: Path, layout=None) -> Path:
    """`bound_map_figure` saved as a PNG."""
    plt = _pyplot()
    fig = bound_map_figure(limit, layout)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def bound_map_figure(limit, layout=None):
    """The physical limit over the skin: per pressed position, the electronics-only Cramér-Rao bound and, when
    the dataset has them, the bound with depth, drift and placement as nuisances and the landing-point bound
    (depth, drift and fabrication); each panel with its own colour bar (they differ by decades: one shared scale
    saturated one panel). All three share one rank rule (`neatskin.skin.fisherbound`), so a position unresolvable
    in one is unresolvable in all.

    Positions are drawn as squares at their (x, y); an unobservable position (+inf) is a red cross, and one whose
    bound exceeds the skin's extent (a press just off a channel the probe shuts: 1e6 mm) an orange one, kept off
    the colour scale (one such position stretched it over six decades, and the rest read as one colour)."""
    from neatskin.baselines.floortext import skin_extent_mm

    plt = _pyplot()
    columns = [("crb_mm", "electronics only")]
    if "crb_nuisance_mm" in limit.columns:
        columns.append(("crb_nuisance_mm", "depth, drift, placement as nuisances"))
    if "landing_bound_mm" in limit.columns:  # report.md's landing-point bound (Floors): its infinite count is here
        columns.append(("landing_bound_mm", "landing point: depth, drift, fabrication as nuisances"))
    x, y = limit["x_mm"].to_numpy(float), limit["y_mm"].to_numpy(float)
    extent = skin_extent_mm(layout, np.column_stack([x, y]))
    spacing = _median_spacing_mm(x, y)
    fig, axes = plt.subplots(1, len(columns), figsize=(6.0 * len(columns), 5.0), squeeze=False, layout="constrained")
    for ax, (column, label) in zip(axes[0], columns):
        bound = limit[column].to_numpy(float)
        infinite = ~np.isfinite(bound)
        beyond = np.isfinite(bound) & (bound > extent)
        ok = np.isfinite(bound) & (bound > 0) & ~beyond
        norm, scale = _panel_norm(bound[ok])
        _draw_layout(ax, layout)
        size = max(8.0, min(400.0, (spacing * 72.0 / 25.4 * 1.6) ** 2))  # about one grid step wide
        image = ax.scatter(x[ok], y[ok], c=bound[ok], norm=norm, cmap="viridis", marker="s", s=size)
        for mask, colour, text in (
            (infinite, "tab:red", f"unobservable (+inf): {int(infinite.sum())}"),
            (beyond, "tab:orange", f"beyond the skin (> {extent:g} mm): {int(beyond.sum())}"),
        ):
            if mask.any():
                ax.plot(x[mask], y[mask], "x", color=colour, ms=7, mew=2, label=text)
        if (infinite | beyond).any():
            ax.legend(loc="upper right", fontsize=8)
        title = f"{label}\nmedian {np.median(bound):.3g} mm over {len(bound)} positions"
        if not (infinite | beyond).any():  # a pooled RMS held by an infinite or huge position says nothing
            title += f", RMS {float(np.sqrt(np.mean(bound * bound))):.3g} mm"
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        fig.colorbar(image, ax=ax, shrink=0.85, label=f"bound on the RMS position error (mm{scale})")
    fig.suptitle("Cramér-Rao bound per pressed position (physical_limit.parquet)", fontsize=10)
    return fig


def _median_spacing_mm(x: np.ndarray, y: np.ndarray) -> float:
    """Median distance from a position to its nearest neighbour (1 mm for a single position)."""
    if len(x) < 2:
        return 1.0
    from scipy.spatial import cKDTree

    xy = np.column_stack([x, y])
    distance, _ = cKDTree(xy).query(xy, k=2)  # the first neighbour is the position itself
    return float(np.median(np.asarray(distance)[:, 1])) or 1.0

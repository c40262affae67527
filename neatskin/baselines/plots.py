"""Report figures: error against compute time per split (log axes), per-position error ellipses as paper Fig. 9, and
the physical limit's bound map."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neatskin.baselines.evaluate import ModelResult
from neatskin.baselines.metrics import PROBE_RADIUS_MM, error_ellipses


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_error_vs_time(results: list[ModelResult], path: Path, bound_rms_mm: float | None = None, table=None) -> Path:
    """Mean error over repeats (bars: 95 % interval of the mean) against time per fit + predict, one panel per split.

    Log axes (errors span decades: the inversion near the bound, extrapolating models far off);
    the paper's 2.03 mm appears only on the random split's panel, the one it is comparable to;
    a result below the Cramér-Rao bound is drawn as a red cross and labelled memorisation.
    """
    plt = _pyplot()
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    splits = list(dict.fromkeys(r.split for r in results))
    models = list(dict.fromkeys(r.model for r in results))
    colours = {m: f"C{i % 10}" for i, m in enumerate(models)}
    fig, axes = plt.subplots(1, len(splits), figsize=(5.0 * len(splits), 5.2), squeeze=False, sharey=True)

    flagged = set()
    if table is not None and "below_bound" in table.columns:  # the report's one rule (report.results_table)
        flagged = {(m, sp) for m, sp, b in zip(table["model"], table["split"], table["below_bound"]) if b}

    def memorised(r: ModelResult) -> bool:
        return (r.model, r.split) in flagged

    # a memorised result can be ~1e-15 mm: it is drawn as a triangle on the axis floor, not at its value
    honest = [r.summary["mean_error_mm"].mean for r in results if not memorised(r)]
    floor = min([v for v in honest if v > 0] + ([bound_rms_mm] if bound_rms_mm else [])) / 4
    for ax, split in zip(axes[0], splits):
        memorisers: list[str] = []
        for r in (r for r in results if r.split == split):
            s = r.summary["mean_error_mm"]
            seconds = max(r.fit_time_s + r.predict_time_per_sample_s * r.per_repeat[0].n, 1e-5)
            if memorised(r):
                ax.plot(seconds, floor, "v", color="black", ms=9, label="memorisation: below the bound")
                memorisers.append(r.model)
                continue
            low, high = max(s.low, floor), s.high
            ax.errorbar(
                seconds,
                s.mean,
                yerr=[[s.mean - low], [high - s.mean]],
                color=colours[r.model],
                fmt="o",
                ms=6,
                capsize=3,
                label=r.model,
            )
        ax.axhline(PROBE_RADIUS_MM, color="grey", ls=":", lw=1, label="probe radius 2.75 mm")
        if split == "random":
            ax.axhline(2.03, color="tab:red", ls="--", lw=1, label="paper, real skin, same split: 2.03 mm")
        if bound_rms_mm is not None and np.isfinite(bound_rms_mm) and bound_rms_mm > 0:
            ax.axhline(
                bound_rms_mm, color="black", ls="-.", lw=1, label=f"Cramér-Rao bound (RMS) {bound_rms_mm:.2g} mm"
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        # ticks at 1, 2, 5 per decade labelled plainly (0.02, 0.05, 0.1): readable within one decade, no collisions
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_ylim(bottom=floor / 2)
        ax.set_xlabel("time per fit + predicting the test rows (s, log)")
        # memorisers named in the title: labels beside each triangle would collide with each other
        note = f"\n▼ memorise (below the bound): {', '.join(memorisers)}" if memorisers else ""
        ax.set_title(f"{split} split{note}", fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    axes[0][0].set_ylabel("mean Euclidean error (mm, log)\nbars: 95 % interval over repeats")
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=min(6, len(labels)))
    fig.suptitle("Position error against compute time (one marker per model; mean over repeated splits)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06 * (1 + (len(labels) - 1) // 6), 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


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


def plot_bound_map(limit, path: Path, layout=None) -> Path:
    """The physical limit over the skin: per pressed position, the electronics-only Cramér-Rao bound and, when
    the dataset has it, the bound with depth, drift and placement as nuisances; one log colour scale for both.

    Positions are drawn as squares at their (x, y); an unobservable position (+inf) is a red cross."""
    from matplotlib.colors import LogNorm

    plt = _pyplot()
    columns = [("crb_mm", "electronics only")]
    if "crb_nuisance_mm" in limit.columns:
        columns.append(("crb_nuisance_mm", "depth, drift, placement as nuisances"))
    x, y = limit["x_mm"].to_numpy(float), limit["y_mm"].to_numpy(float)
    values = np.concatenate([limit[c].to_numpy(float) for c, _ in columns])
    finite = values[np.isfinite(values) & (values > 0)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (1e-3, 1.0)
    if hi <= lo * 1.01:  # one value: a decade around it, so the scale still reads
        lo, hi = lo / np.sqrt(10.0), hi * np.sqrt(10.0)
    norm = LogNorm(vmin=lo, vmax=hi)
    spacing = _median_spacing_mm(x, y)
    fig, axes = plt.subplots(1, len(columns), figsize=(5.0 * len(columns) + 1.0, 4.8), squeeze=False)
    image = None
    for ax, (column, label) in zip(axes[0], columns):
        bound = limit[column].to_numpy(float)
        ok = np.isfinite(bound) & (bound > 0)
        _draw_layout(ax, layout)
        size = max(8.0, min(400.0, (spacing * 72.0 / 25.4 * 1.6) ** 2))  # about one grid step wide
        image = ax.scatter(x[ok], y[ok], c=bound[ok], norm=norm, cmap="viridis", marker="s", s=size)
        if (~ok).any():
            ax.plot(x[~ok], y[~ok], "x", color="tab:red", ms=7, label="unobservable (+inf)")
            ax.legend(loc="upper right", fontsize=8)
        rms = float(np.sqrt(np.mean(bound * bound)))
        ax.set_title(
            f"{label}\nmedian {np.median(bound):.3g} mm, RMS {rms:.3g} mm ({len(bound)} positions)", fontsize=9
        )
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    fig.colorbar(image, ax=axes[0].tolist(), label="Cramér-Rao bound on the RMS position error (mm, log)")
    fig.suptitle("Physical limit per pressed position (physical_limit.parquet)", fontsize=10)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _median_spacing_mm(x: np.ndarray, y: np.ndarray) -> float:
    """Median distance from a position to its nearest neighbour (1 mm for a single position)."""
    if len(x) < 2:
        return 1.0
    from scipy.spatial import cKDTree

    xy = np.column_stack([x, y])
    distance, _ = cKDTree(xy).query(xy, k=2)  # the first neighbour is the position itself
    return float(np.median(np.asarray(distance)[:, 1])) or 1.0

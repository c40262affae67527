"""Report figures: error against fit time (log x), and per-position error ellipses as paper Fig. 9."""

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


def plot_error_vs_time(results: list[ModelResult], path: Path, bound_rms_mm: float | None = None) -> Path:
    """Mean Euclidean error (with std bars) against mean fit time per fit, one marker per model and split."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.8))
    markers = {"grouped": "o", "random": "s"}
    models = list(dict.fromkeys(r.model for r in results))
    colours = {m: f"C{i % 10}" for i, m in enumerate(models)}
    for r in results:
        ax.errorbar(
            r.fit_time_s,
            r.errors.mean_error_mm,
            yerr=r.errors.std_error_mm,
            color=colours[r.model],
            fmt=markers.get(r.split, "o"),
            capsize=3,
            label=f"{r.model} ({r.split})",
        )
        ax.annotate(
            r.model, (r.fit_time_s, r.errors.mean_error_mm), textcoords="offset points", xytext=(5, 5), fontsize=8
        )
    ax.axhline(PROBE_RADIUS_MM, color="grey", ls=":", lw=1, label="probe radius 2.75 mm")
    ax.axhline(2.03, color="tab:red", ls="--", lw=1, label="paper, real skin: 2.03 mm")
    if bound_rms_mm is not None and np.isfinite(bound_rms_mm):
        ax.axhline(bound_rms_mm, color="black", ls="-.", lw=1, label=f"Cramér-Rao bound (RMS) {bound_rms_mm:.3g} mm")
    ax.set_xscale("log")
    ax.set_xlabel("fit time per fit (s, log)")
    ax.set_ylabel("mean Euclidean error (mm), bars: std")
    ax.set_ylim(bottom=0)
    ax.set_title("Position error against fit time (circles: grouped split, squares: random split)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
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
    """One panel per model: probe circles at true positions, mean predictions, 1-std ellipses, error lines."""
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
        for g in keep:
            t, m = ell.true_mm[g], ell.mean_pred_mm[g]
            hit = ell.centre_error_mm[g] <= PROBE_RADIUS_MM
            ax.add_patch(Circle(t, PROBE_RADIUS_MM, fill=False, color="tab:blue", lw=0.6))
            ax.add_patch(
                Ellipse(
                    m,
                    2 * ell.std_axes_mm[g, 0],
                    2 * ell.std_axes_mm[g, 1],
                    angle=np.degrees(ell.angle_rad[g]),
                    color="tab:green",
                    alpha=0.45,
                )
            )
            ax.plot([t[0], m[0]], [t[1], m[1]], color="black" if hit else "tab:red", lw=0.8)
            ax.plot(m[0], m[1], ".", color="tab:green", ms=3)
        ax.set_aspect("equal")
        # one view for every panel: the pressed area and a probe diameter around it, so panels compare;
        # a mean prediction that lands outside is drawn to the edge and counted in the title
        lo = ell.true_mm.min(axis=0) - 2 * PROBE_RADIUS_MM
        hi = ell.true_mm.max(axis=0) + 2 * PROBE_RADIUS_MM
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        outside = int(np.sum(np.any((ell.mean_pred_mm[keep] < lo) | (ell.mean_pred_mm[keep] > hi), axis=1)))
        note = f", {outside} mean(s) off the view" if outside else ""
        ax.set_title(f"{r.model} ({r.split}): {r.errors.mean_error_mm:.2f} mm{note}", fontsize=9)
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

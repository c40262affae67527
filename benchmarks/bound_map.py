"""The position bound as a map over the skin: electronics only beside depth, drift and placement as nuisances, for a
protocol's own dry-run scene (default protocols/paper.toml: the paper-like scene, FE pinch kernel, placement 0.7 mm).

    python benchmarks/bound_map.py [--protocol protocols/paper.toml] [--out out/bound_map.png] [--step-mm 0.5]

Everything comes from the protocol, as the dry run's `physical_limit.parquet` takes it (neatskin.rig.physlimit):
the skin is the dry run's (`simcampaign.skin_of`: its pinch, the seed's fabrication spread), the press depth is the
protocol's, the noise is one press's dR std per pair at the unpressed skin (`simcampaign.pair_noise_std_ohm`: the
DAQ estimator at the protocol's current), and the priors are `NuisancePriors.from_scene` (the scene's depth jitter
and placement error; the drift ramp over the campaign, ptp / sqrt(12)). Unlike physlimit it evaluates a grid, not
the campaign's positions, with the unpressed noise everywhere, and no fabrication nuisance.

Prints the median and the 10/90 % points of each map over its finite points, and how many grid points are
infinite (around a junction, where every channel the probe reaches is shut and the others are beyond the pinch's
reach: moving within that spot changes nothing a graded reading sees), and writes a
three-panel PNG (log colour scale up to the skin's 30 mm, channels drawn, infinite points in red, finite ones
beyond 30 mm in orange).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
ROWS_AT_ONCE = 4  # grid rows per skin call: the kernel skin's work arrays stay small
BEYOND_SKIN_MM = 30.0  # a finite bound larger than the skin says no more than an infinite one: drawn apart


def bound_grid(skin, bounds, depth_mm: float, noise_std_ohm, step_mm: float, **priors: float):
    """The bound on a grid over bounds = (x0, y0, x1, y1): x (nx,), y (ny,), bound (ny, nx) in mm, row block by
    row block (the same numbers as neatskin.skin.bound.bound_map_mm, which evaluates the grid at once)."""
    from neatskin.skin.bound import feature_jacobian, position_bound_mm

    x0, y0, x1, y1 = bounds
    xs = np.arange(x0, x1 + 1e-9, step_mm)
    ys = np.arange(y0, y1 + 1e-9, step_mm)
    rows = []
    for start in range(0, ys.size, ROWS_AT_ONCE):
        gx, gy = np.meshgrid(xs, ys[start : start + ROWS_AT_ONCE])
        jac = feature_jacobian(skin, gx.ravel(), gy.ravel(), np.full(gx.size, depth_mm))
        rows.append(position_bound_mm(jac, noise_std_ohm, **priors).reshape(gx.shape))
    return xs, ys, np.vstack(rows)


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from neatskin.rig.physlimit import NuisancePriors
    from neatskin.rig.plan import build_plan
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.simcampaign import pair_noise_std_ohm, skin_of

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", default=str(REPO / "protocols" / "paper.toml"))
    parser.add_argument("--out", default="out/bound_map.png")
    parser.add_argument("--step-mm", type=float, default=0.5)
    args = parser.parse_args()
    protocol = load_protocol(args.protocol)
    plan = build_plan(protocol)
    scene = protocol.scene
    skin = skin_of(protocol)
    depth = protocol.press.press.depth_mm
    noise = pair_noise_std_ohm(protocol)
    interval_s = float(getattr(scene, "press_interval_s", 0.0))
    campaign_s = interval_s * plan.n_presses if interval_s else float(plan.printer_time_s)
    priors = NuisancePriors.from_scene(scene, campaign_s)
    layout = protocol.layout
    print(
        f"{args.protocol}: {scene.preset} scene, {skin.deformation} pinch, depth {depth:g} mm, "
        f"{1e3 * protocol.excitation.amplitude_a:g} mA; dR noise {noise.min():.3g} to {noise.max():.3g} ohm per pair; "
        f"priors: depth {priors.depth_std_mm:g} mm, log rho {priors.drift_std:.3g}, placement "
        f"{priors.placement_std_mm:g} mm per axis"
    )
    bounds = layout.bounds_mm
    panels = {
        "electronics only": {},
        "depth + drift nuisances": {"depth_std_mm": priors.depth_std_mm, "drift_std": priors.drift_std},
        f"+ placement {priors.placement_std_mm:g} mm": priors.as_kwargs(),
    }
    maps = {title: bound_grid(skin, bounds, depth, noise, args.step_mm, **kw) for title, kw in panels.items()}
    fig, axes = plt.subplots(1, len(maps), figsize=(5 * len(maps), 4.4), constrained_layout=True)
    values = np.concatenate([b[np.isfinite(b)] for _, _, b in maps.values()])
    norm = LogNorm(vmin=max(values.min(), 1e-4), vmax=min(values.max(), BEYOND_SKIN_MM))
    a, b = layout.xy_mm[layout.channel_ends[:, 0]], layout.xy_mm[layout.channel_ends[:, 1]]
    image = None
    for ax, (title, (x, y, bound)) in zip(axes, maps.items()):
        finite = np.isfinite(bound)
        q = np.percentile(bound[finite], [10, 50, 90]) if finite.any() else np.full(3, np.nan)
        beyond = finite & (bound > BEYOND_SKIN_MM)
        print(
            f"  {title:<26s} median {q[1]:.4g} mm (10 % {q[0]:.3g}, 90 % {q[2]:.3g}) over the finite points; "
            f"infinite at {int((~finite).sum())} of {bound.size} grid points, finite beyond the skin "
            f"(> {BEYOND_SKIN_MM:g} mm) at {int(beyond.sum())}"
        )
        shown = np.where(finite & ~beyond, bound, np.nan)
        image = ax.pcolormesh(x, y, shown, norm=norm, shading="nearest", cmap="viridis")
        gx, gy = np.meshgrid(x, y)
        ax.plot(gx[~finite], gy[~finite], "r.", ms=1.5)
        ax.plot(gx[beyond], gy[beyond], "o", color="orange", ms=3)
        for p, r in zip(a, b):
            ax.plot([p[0], r[0]], [p[1], r[1]], "w--", lw=0.8)
        ax.set_title(f"{title}\nmedian {q[1]:.3g} mm, infinite at {int((~finite).sum())} (red)")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
    axes[0].set_ylabel("y (mm)")
    fig.colorbar(image, ax=axes, label="RMS position error bound (mm)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

"""The position bound as a map: electronics only beside depth, drift and placement as nuisances (paper-like priors).

    python benchmarks/bound_map.py [--out out/bound_map.png] [--step-mm 0.5]

Prints the median and the 10/90 % points of each map and writes a two-panel PNG (log colour scale,
channels drawn). Noise: 0.1 ohm per reading, two readings per dR. Priors (paper-like scene):
depth 0.2 mm, log-resistivity 0.02 (the drift of 0.012 /h spread over a 6 h campaign, ptp / sqrt(12)),
placement 1.35 mm per axis.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from neatskin.layout import load_layout
from neatskin.skin.bound import bound_map_mm
from neatskin.skin.model import SkinModel

REPO = Path(__file__).resolve().parent.parent
NOISE_OHM = 0.1 * np.sqrt(2)
PRIORS = {"depth_std_mm": 0.2, "drift_std": 0.012 * 6.05 / np.sqrt(12), "placement_std_mm": 1.35}


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bound_map.png")
    parser.add_argument("--step-mm", type=float, default=0.5)
    args = parser.parse_args()
    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    skin = SkinModel(layout)
    bounds = (0.0, 0.0, 30.0, 30.0)
    maps = {
        "electronics only": bound_map_mm(skin, bounds, 3.5, NOISE_OHM, args.step_mm),
        "depth + drift nuisances": bound_map_mm(
            skin,
            bounds,
            3.5,
            NOISE_OHM,
            args.step_mm,
            depth_std_mm=PRIORS["depth_std_mm"],
            drift_std=PRIORS["drift_std"],
        ),
        "+ placement 1.35 mm": bound_map_mm(skin, bounds, 3.5, NOISE_OHM, args.step_mm, **PRIORS),
    }
    fig, axes = plt.subplots(1, len(maps), figsize=(5 * len(maps), 4.4), constrained_layout=True)
    values = np.concatenate([b[np.isfinite(b)] for _, _, b in maps.values()])
    norm = LogNorm(vmin=max(values.min(), 1e-4), vmax=values.max())
    a, b = layout.xy_mm[layout.channel_ends[:, 0]], layout.xy_mm[layout.channel_ends[:, 1]]
    for ax, (title, (x, y, bound)) in zip(axes, maps.items()):
        q = np.nanpercentile(np.where(np.isfinite(bound), bound, np.nan), [10, 50, 90])
        print(
            f"  {title:<26s} median {q[1]:.4g} mm (10 % {q[0]:.3g}, 90 % {q[2]:.3g}); infinite at {np.isinf(bound).sum()}"
        )
        image = ax.pcolormesh(x, y, bound, norm=norm, shading="nearest", cmap="viridis")
        for p, r in zip(a, b):
            ax.plot([p[0], r[0]], [p[1], r[1]], "w--", lw=0.8)
        ax.set_title(f"{title}\nmedian {q[1]:.3g} mm")
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

"""The depth question the paper leaves open: press depth against the share of channels shut, the share of
presses with an open circuit (a pair whose electrodes are cut apart: R_eq = inf, the galvanostat clips), and the
localisation error of a simple learned baseline; for the parametric pinch and the FE kernel.

A small dry simulation through skin/ only (not the rig): per campaign seed, 100 random positions x 28 presses,
each landed with the paper-like preset's placement error and depth jitter (neatskin/config/scene.py), R_eq of the 28 pairs
plus 1 ohm of reading noise, an open pair clipped at 4x the largest baseline R_eq. Localisation: k-nearest
neighbours (k = 5, distance-weighted) on the standardised dR of the 28 pairs, a random 80/20 split of the presses
(the paper's split is by press too). Not the paper's LM network: a like-for-like comparison across depths.

    python benchmarks/bench_depth.py [--seeds 3] [--out out/bench-depth]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
from sklearn.model_selection import train_test_split
from sklearn.neighbors import KNeighborsRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from neatskin.config.scene import PAPER_LIKE
from neatskin.layout import load_layout
from neatskin.skin.kernel import packaged_kernel_path, read_kernel
from neatskin.skin.model import SkinModel

DEPTHS_MM = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
PLACEMENT_MM, JITTER_MM = PAPER_LIKE["placement_error_mm"], PAPER_LIKE["depth_jitter_mm"]


def campaign(model: SkinModel, depth_mm: float, seed: int):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(1.0, 30.0, (100, 2))
    cmd = np.repeat(pos, 28, axis=0)
    landed = cmd + PLACEMENT_MM * rng.standard_normal(cmd.shape)
    depth = depth_mm + JITTER_MM * rng.standard_normal(cmd.shape[0])
    resistance = model.channel_resistance_ohm(landed[:, 0], landed[:, 1], depth)
    shut = np.isinf(resistance).mean(axis=1)
    r_eq = model.pair_resistance_ohm(landed[:, 0], landed[:, 1], depth)
    base = model.baseline_pair_resistance_ohm
    open_circuit = np.isinf(r_eq).any(axis=1)
    reading = np.minimum(r_eq, 4 * base.max()) + rng.normal(0.0, 1.0, r_eq.shape)
    return cmd, reading - base, shut, open_circuit


def localisation_error_mm(features, target, seed: int) -> float:
    x_tr, x_te, y_tr, y_te = train_test_split(features, target, test_size=0.2, random_state=seed)
    knn = make_pipeline(StandardScaler(), KNeighborsRegressor(n_neighbors=5, weights="distance"))
    knn.fit(x_tr, y_tr)
    return float(np.mean(np.hypot(*(knn.predict(x_te) - y_te).T)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", default="out/bench-depth")
    args = parser.parse_args()
    layout = load_layout("protocols/skins/paper.toml")
    models = {
        "parametric": SkinModel(layout),
        "fe-kernel": SkinModel(layout, kernel=read_kernel(packaged_kernel_path())),
    }
    rows = []
    for name, model in models.items():
        for depth in DEPTHS_MM:
            shut, opened, error = [], [], []
            for seed in range(args.seeds):
                cmd, features, s, o = campaign(model, depth, seed)
                shut.append(s.mean())
                opened.append(o.mean())
                error.append(localisation_error_mm(features, cmd, seed))
            rows.append(
                (
                    name,
                    depth,
                    np.mean(shut),
                    np.std(shut),
                    np.mean(opened),
                    np.std(opened),
                    np.mean(error),
                    np.std(error),
                )
            )
    load = os.getloadavg()[0]
    print(
        f"{args.seeds} campaign seeds x 2,800 presses per row, placement {PLACEMENT_MM} mm, depth jitter "
        f"{JITTER_MM} mm; mean +- std over seeds; load average {load:.1f}"
    )
    print("| model | depth (mm) | channels shut | presses with an open pair | KNN error (mm) |")
    print("|---|---:|---:|---:|---:|")
    for name, d, s, ss, o, os_, e, es in rows:
        print(
            f"| {name} | {d:.1f} | {100 * s:.1f} +- {100 * ss:.1f} % | {100 * o:.1f} +- {100 * os_:.1f} % | {e:.2f} +- {es:.2f} |"
        )
    for name in models:
        sel = [r for r in rows if r[0] == name]
        best = min(sel, key=lambda r: r[6])
        print(f"{name}: lowest KNN error at {best[1]:.1f} mm ({best[6]:.2f} +- {best[7]:.2f} mm)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for name in models:
        sel = [r for r in rows if r[0] == name]
        d = [r[1] for r in sel]
        for ax, (m, s), label in zip(
            axes,
            ((2, 3), (4, 5), (6, 7)),
            ("channels shut (share)", "presses with an open pair (share)", "KNN localisation error (mm)"),
        ):
            ax.errorbar(d, [r[m] for r in sel], yerr=[r[s] for r in sel], marker="o", capsize=3, label=name)
            ax.set(xlabel="press depth (mm)", ylabel=label)
            ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(
        f"paper skin, paper-like placement {PLACEMENT_MM} mm and depth jitter {JITTER_MM} mm, {args.seeds} seeds",
        fontsize=10,
    )
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "depth.png", dpi=110)
    print(out / "depth.png")


if __name__ == "__main__":
    main()

"""Coverage of `skin fit`'s 95 % intervals where a real campaign lives: 100 simulated campaigns (seeds) at each of
0, 0.6 and 1.35 mm placement error, every interval checked against the known truth.

    python benchmarks/bench_fit_coverage.py [--seeds 100] [--placements 0 0.6 1.35] [--jobs 2]

Each campaign: 40 uniform positions x 8 presses on the paper skin, 3.5 mm deep, a changed skin profile (pinch_gain
0.8, decay_ratio 0.5, channel heights spread 8 %), 0.5 ohm reading noise on the baseline and the pressed reading (so
dR's noise is 0.5 sqrt(2)), the paper-like drift (0.5 K/h at -0.02 /K and 0.002 /h evaporation, 7.78 s per press).
The drift's truth is the least-squares slope of log rho over the presses' times (what a straight line can hold),
not the initial slope. Printed: held of 100 per parameter (channels: of 1,200), the binomial(100, 0.95) band
(90..99 but for a 1-in-1,000 chance each side), and the pinch's mean z-score (bias).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
INTERVAL_S, NOISE_OHM, PINCH = 7.78, 0.5, (0.8, 0.5)
POSITIONS, REPEATS = 40, 8


def write_campaign(folder: Path, seed: int, placement_mm: float) -> dict:
    import pandas as pd

    from neatskin.layout import load_layout
    from neatskin.skin.deformation import PinchParams
    from neatskin.skin.model import SkinModel
    from neatskin.skin.variability import drift_resistivity_factor, fabrication_heights

    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    rng = np.random.default_rng([seed, 23])
    skin = SkinModel(
        layout, pinch=PinchParams(*PINCH), channel_height_factor=fabrication_heights(layout.n_channels, 0.08, seed)
    )
    xy = rng.uniform(1.0, 29.0, (POSITIONS, 2))
    pos = np.repeat(np.arange(POSITIONS), REPEATS)
    n = pos.size
    landed = xy[pos] + (rng.normal(0, placement_mm, (n, 2)) if placement_mm else 0.0)
    t_s = np.arange(n) * INTERVAL_S
    rho = drift_resistivity_factor(t_s, 0.5, 0.002, -0.02)
    pressed = skin.pair_resistance_ohm(landed[:, 0], landed[:, 1], 3.5, resistivity_factor=rho)
    base = skin.baseline_pair_resistance_ohm[None] * rho[:, None]
    pressed = pressed + rng.normal(0, NOISE_OHM, pressed.shape)
    base = base + rng.normal(0, NOISE_OHM, base.shape)
    df = pd.DataFrame(
        {"press_id": np.arange(n), "position_id": pos, "x_mm": xy[pos, 0], "y_mm": xy[pos, 1], "depth_mm": 3.5}
    )
    names = [f"{p.i}_{p.j}" for p in layout.pairs]
    for k, name in enumerate(names):
        df[f"R_ohm_{name}"] = pressed[:, k]
    for k, name in enumerate(names):
        df[f"dR_ohm_{name}"] = pressed[:, k] - base[:, k]
    folder.mkdir(parents=True)
    df.to_parquet(folder / "presses.parquet")
    (folder / "manifest.json").write_text(json.dumps({"printer_time_estimate_s": n * INTERVAL_S}))
    (folder / "inputs").mkdir()
    shutil.copyfile(REPO / "protocols" / "skins" / "paper.toml", folder / "inputs" / "layout.toml")
    hours = t_s / 3600
    slope = float(np.polyfit(hours, np.log(rho), 1)[0])  # the least-squares slope: the drift's truth
    return {"channels": skin.channel_baseline_ohm, "drift": slope, "placement": placement_mm}


def one(seed: int, placement_mm: float) -> dict:
    from neatskin.skin.fit import fit_skin

    with tempfile.TemporaryDirectory() as tmp:
        truth = write_campaign(Path(tmp) / "c", seed, placement_mm)
        fit = fit_skin(Path(tmp) / "c")

    def inside(v, t):
        return bool(v.ci95[0] <= t <= v.ci95[1])

    half = (fit.pinch_gain.ci95[1] - fit.pinch_gain.ci95[0]) / 2
    return {
        "channels": sum(inside(v, t) for v, t in zip(fit.channel_resistance_ohm, truth["channels"], strict=True)),
        "pinch_gain": inside(fit.pinch_gain, PINCH[0]),
        "decay_ratio": inside(fit.decay_ratio, PINCH[1]),
        "drift_per_h": inside(fit.drift_per_h, truth["drift"]),
        "noise_ohm": inside(fit.noise_ohm, NOISE_OHM * np.sqrt(2)),
        "placement_error_mm": inside(fit.placement_error_mm, placement_mm),
        "pinch_z": (fit.pinch_gain.value - PINCH[0]) / (half / 1.96) if half > 0 else np.nan,
        "pinch": fit.pinch_gain.value,
    }


def main() -> None:
    from joblib import Parallel, delayed
    from scipy.stats import binom

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--placements", type=float, nargs="*", default=[0.0, 0.6, 1.35])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    started = time.perf_counter()
    lo, hi = int(binom.ppf(0.001, args.seeds, 0.95)), int(binom.isf(0.001, args.seeds, 0.95))
    print(
        f"{args.seeds} seeds per row; binomial({args.seeds}, 0.95) band {lo}..{hi} (1-in-1,000 each side); "
        f"channels of {12 * args.seeds}"
    )
    print("| placement mm | channels | pinch_gain | decay_ratio | drift | noise | placement | pinch mean (z mean) |")
    print("|---|---|---|---|---|---|---|---|")
    for s in args.placements:
        rows = Parallel(n_jobs=args.jobs)(delayed(one)(seed, s) for seed in range(1, args.seeds + 1))
        held = {k: int(sum(r[k] for r in rows)) for k in rows[0] if k not in ("pinch_z", "pinch")}
        z = np.array([r["pinch_z"] for r in rows])
        pinch = np.array([r["pinch"] for r in rows])
        print(
            f"| {s:g} | {held['channels']} | {held['pinch_gain']} | {held['decay_ratio']} | {held['drift_per_h']} "
            f"| {held['noise_ohm']} | {held['placement_error_mm']} | {pinch.mean():.3f} ({np.nanmean(z):+.2f}) |",
            flush=True,
        )
    print(f"load {os.getloadavg()[0]:.1f}; {time.perf_counter() - started:.0f} s wall, {args.jobs} processes")


if __name__ == "__main__":
    main()

"""The paper dry run's headline over campaign seeds, not one: LM network on the random 95/3/2 split (mean error,
share within 2.75 mm), on new positions (grouped 5-fold split), mean +- std over >= 5 campaign seeds; and the Fig. 8
left/right asymmetry over >= 30 seeds.

    python benchmarks/bench_paper_seeds.py [--seeds 5] [--asymmetry-seeds 31] [--networks 5] [--jobs 2]

Each campaign seed is a whole draw: the skin's fabrication (the protocol's seed), the positions, placement, depth
jitter and noise. Campaigns come from the simulated-campaign engine (`neatskin.rig.simcampaign`, the engine of
`neatskin campaign plan`) at the paper protocol (100 positions x 28 presses, paper-like scene), not from the full
pty dry run (3 min per campaign at load 8; the engine leaves out relaxation dents and the double layer's mean
reading, docs/campaigns.md). Per seed: `--networks` LM networks (1 restart each, as the report's repeats), each on a
fresh 95/3/2 split, trained on train + validation rows; the grouped split is 5-fold over positions, one network per
fold. Fig. 8: mean peak |dR| of presses with x > 27 mm over those with x < 3 mm (1.0 for a symmetric skin).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
PROBE_RADIUS_MM = 2.75


def campaign(protocol, seed: int):
    from neatskin.rig.simcampaign import pair_noise_std_ohm, press_interval_s, simulate_presses, strategy_positions

    proto = dataclasses.replace(protocol, seed=int(seed))
    press = proto.press
    xy = strategy_positions(proto, press.positions.count, seed)
    return simulate_presses(
        proto,
        xy,
        press.press.repeats,
        press.press.depth_mm,
        seed,
        pair_noise_std_ohm(proto),
        interval_s=press_interval_s(proto),
    )


def seed_statistics(protocol, seed: int, networks: int) -> dict:
    from sklearn.model_selection import GroupKFold

    from neatskin.baselines.evaluate import paper_split
    from neatskin.baselines.lm import LMNetworkRegressor

    c = campaign(protocol, seed)
    x, y = c.features, c.commanded_mm
    random_err, within = [], []
    for k in range(networks):
        train, val, test = paper_split(len(x), random_state=seed * 1000 + k)
        rows = np.concatenate([train, val])
        model = LMNetworkRegressor(n_restarts=1, random_state=seed * 1000 + k).fit(x[rows], y[rows])
        err = np.linalg.norm(model.predict(x[test]) - y[test], axis=1)
        random_err.append(err.mean())
        within.append(np.mean(err <= PROBE_RADIUS_MM))
    grouped = []
    for k, (train, test) in enumerate(GroupKFold(5).split(x, groups=c.groups)):
        model = LMNetworkRegressor(n_restarts=1, random_state=seed * 1000 + k).fit(x[train], y[train])
        grouped.append(np.linalg.norm(model.predict(x[test]) - y[test], axis=1))
    return {
        "random_mm": float(np.mean(random_err)),
        "within_pct": 100 * float(np.mean(within)),
        "grouped_mm": float(np.mean(np.concatenate(grouped))),
    }


def asymmetry(protocol, seed: int) -> float:
    c = campaign(protocol, seed)
    peak = np.abs(c.features).max(axis=1)
    right, left = c.commanded_mm[:, 0] > 27.0, c.commanded_mm[:, 0] < 3.0
    return float(peak[right].mean() / peak[left].mean()) if right.any() and left.any() else float("nan")


def main() -> None:
    from joblib import Parallel, delayed

    from neatskin.rig.protocol import load_protocol

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--asymmetry-seeds", type=int, default=31)
    parser.add_argument("--networks", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    protocol = load_protocol(REPO / "protocols" / "paper.toml")
    seeds = [2019] + list(range(1, args.seeds))
    started = time.perf_counter()
    stats = Parallel(n_jobs=args.jobs)(delayed(seed_statistics)(protocol, s, args.networks) for s in seeds)
    ratios = Parallel(n_jobs=args.jobs)(
        delayed(asymmetry)(protocol, s) for s in [2019, *range(1, args.asymmetry_seeds)]
    )
    print(
        f"paper protocol, paper-like scene, simulated-campaign engine; load {os.getloadavg()[0]:.1f}; "
        f"{time.perf_counter() - started:.0f} s wall, {args.jobs} processes"
    )
    print("| campaign seed | LM random split: mean error mm | within 2.75 mm % | LM grouped split (new positions) mm |")
    print("|---|---|---|---|")
    for s, r in zip(seeds, stats, strict=True):
        print(f"| {s} | {r['random_mm']:.2f} | {r['within_pct']:.1f} | {r['grouped_mm']:.2f} |")
    cells = {k: np.array([r[k] for r in stats]) for k in stats[0]}
    print(
        f"| mean +- std over {len(seeds)} seeds | {cells['random_mm'].mean():.2f} +- {cells['random_mm'].std(ddof=1):.2f} "
        f"| {cells['within_pct'].mean():.1f} +- {cells['within_pct'].std(ddof=1):.1f} "
        f"| {cells['grouped_mm'].mean():.2f} +- {cells['grouped_mm'].std(ddof=1):.2f} |"
    )
    ratios_a = np.array(ratios)
    print(
        f"Fig. 8 right/left peak |dR| over {len(ratios_a)} seeds: {np.nanmean(ratios_a):.2f} +- "
        f"{np.nanstd(ratios_a, ddof=1):.2f} (seed 2019: {ratios_a[0]:.2f}; share > 1: {np.mean(ratios_a > 1):.2f})"
    )


if __name__ == "__main__":
    main()

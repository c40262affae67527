"""Per-press cost of the skin model: the parametric pinch against the finite-element kernel ("fe-kernel"), as the
dry probe calls it (one press = one call with its few probe states), alternating in one process; with --base DIR
(repeatable), also the skins of other checkouts (e.g. worktrees of the base commits), each in a fresh subprocess per
round, alternating with this tree's: the parametric skin always, the fe-kernel skin where that tree has one. For the
"at most 1.2 times today's per-press skin" target: this tree's fe-kernel over the old base's parametric skin.

    python benchmarks/bench_kernel_skin.py [--presses 300] [--states 8] [--rounds 3] [--base /tmp/base-wt ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def per_press_ms(model, x, y, depth) -> float:
    t0 = time.process_time()
    for i in range(x.shape[0]):
        model.pair_resistance_ohm(np.full(depth.shape[1], x[i]), np.full(depth.shape[1], y[i]), depth[i])
    return 1e3 * (time.process_time() - t0) / x.shape[0]


def presses(n: int, states: int):
    rng = np.random.default_rng(0)
    x, y = rng.uniform(1, 29, n), rng.uniform(1, 29, n)
    depth = np.linspace(0.5, 3.5, states)[None, :] + rng.normal(0, 0.2, (n, 1))
    return x, y, depth


def make_model(name: str, root: Path):
    from neatskin.layout import load_layout
    from neatskin.skin.model import SkinModel

    layout = load_layout(root / "protocols/skins/paper.toml")
    if name == "parametric":
        return SkinModel(layout)
    from neatskin.skin.kernel import packaged_kernel_path, read_kernel  # not in trees older than the kernel

    return SkinModel(layout, kernel=read_kernel(packaged_kernel_path()))


def has_kernel(root: Path) -> bool:
    return (root / "neatskin" / "skin" / "kernelpinch.py").exists()


def in_subprocess(root: Path, name: str, n: int, states: int) -> float:
    """Per-press ms of `root`'s `name` skin, measured in a fresh interpreter with `root` on the path."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    cmd = [sys.executable, __file__, "--one", str(root), "--model", name, "--presses", str(n), "--states", str(states)]
    return float(json.loads(subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presses", type=int, default=300)
    parser.add_argument("--states", type=int, default=8, help="probe states per press (depths along the stroke)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--base", type=Path, action="append", default=[], help="a checkout whose skins to time beside this tree's"
    )
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # subprocess mode: one timing
    parser.add_argument("--model", default="parametric", help=argparse.SUPPRESS)
    args = parser.parse_args()
    x, y, depth = presses(args.presses, args.states)
    if args.one is not None:
        model = make_model(args.model, args.one)
        per_press_ms(model, x[:20], y[:20], depth[:20])
        print(json.dumps(per_press_ms(model, x, y, depth)))
        return
    here = Path(__file__).resolve().parents[1]
    models = {name: make_model(name, here) for name in ("parametric", "fe-kernel")}
    for model in models.values():
        per_press_ms(model, x[:20], y[:20], depth[:20])  # warm up
    times: dict[str, list[float]] = {name: [] for name in models}
    others = [
        (root.resolve(), name)
        for root in args.base
        for name in ("parametric", "fe-kernel")
        if name == "parametric" or has_kernel(root)
    ]
    for root, name in others:
        times[f"{root.name} {name}"] = []
    load_start = os.getloadavg()[0]
    for _ in range(args.rounds):
        for name, model in models.items():
            times[name].append(per_press_ms(model, x, y, depth))
        for root, name in others:
            times[f"{root.name} {name}"].append(in_subprocess(root, name, args.presses, args.states))
    load = os.getloadavg()[0]
    print(
        f"{args.presses} presses x {args.states} states, CPU ms per press, load average {load_start:.1f} -> {load:.1f}"
    )
    for name, values in times.items():
        print(f"  {name:<28s} median {np.median(values):.3f}  ({', '.join(f'{v:.3f}' for v in values)})")
    mine = np.median(times["fe-kernel"])
    print(f"  fe-kernel / parametric (this tree): {mine / np.median(times['parametric']):.2f}")
    for root, name in others:
        print(f"  fe-kernel / {root.name} {name}: {mine / np.median(times[f'{root.name} {name}']):.2f}")


if __name__ == "__main__":
    main()

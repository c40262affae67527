"""Per-press cost of the skin model: the parametric pinch against the finite-element kernel ("fe-kernel"), as the
dry probe calls it (one press = one call with its few probe states), alternating in one process; with --base DIR,
also the parametric skin of another checkout (e.g. a worktree of the base commit) in a subprocess per round,
alternating with this tree's, for the "at most 1.2 times today's per-press skin" target.

    python benchmarks/bench_kernel_skin.py [--presses 300] [--states 8] [--rounds 3] [--base /tmp/base-wt]
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


def in_subprocess(root: Path, n: int, states: int) -> float:
    """Per-press ms of `root`'s parametric skin, measured in a fresh interpreter with `root` on the path."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    cmd = [sys.executable, __file__, "--one", str(root), "--presses", str(n), "--states", str(states)]
    return float(json.loads(subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presses", type=int, default=300)
    parser.add_argument("--states", type=int, default=8, help="probe states per press (depths along the stroke)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--base", type=Path, help="a checkout whose parametric skin to time beside this tree's")
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # subprocess mode: one parametric timing
    args = parser.parse_args()
    x, y, depth = presses(args.presses, args.states)
    if args.one is not None:
        model = make_model("parametric", args.one)
        per_press_ms(model, x[:20], y[:20], depth[:20])
        print(json.dumps(per_press_ms(model, x, y, depth)))
        return
    here = Path(__file__).resolve().parents[1]
    models = {name: make_model(name, here) for name in ("parametric", "fe-kernel")}
    for model in models.values():
        per_press_ms(model, x[:20], y[:20], depth[:20])  # warm up
    times: dict[str, list[float]] = {name: [] for name in models}
    if args.base is not None:
        times["base parametric"] = []
    for _ in range(args.rounds):
        for name, model in models.items():
            times[name].append(per_press_ms(model, x, y, depth))
        if args.base is not None:
            times["base parametric"].append(in_subprocess(args.base.resolve(), args.presses, args.states))
    load = os.getloadavg()
    print(f"{args.presses} presses x {args.states} states, CPU ms per press, load average {load[0]:.1f}")
    for name, values in times.items():
        print(f"  {name:<16s} median {np.median(values):.3f}  ({', '.join(f'{v:.3f}' for v in values)})")
    print(f"  fe-kernel / parametric: {np.median(times['fe-kernel']) / np.median(times['parametric']):.2f}")
    if args.base is not None:
        ratio = np.median(times["fe-kernel"]) / np.median(times["base parametric"])
        print(f"  fe-kernel / base parametric ({args.base}): {ratio:.2f}")


if __name__ == "__main__":
    main()

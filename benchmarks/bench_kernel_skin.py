"""Per-press cost of the skin model: the parametric pinch against the finite-element kernel ("fe-kernel"), as the
dry probe calls it (one press = one call with its few probe states), alternating in one process.

    python benchmarks/bench_kernel_skin.py [--presses 300] [--states 8] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from neatskin.layout import load_layout
from neatskin.skin.kernel import packaged_kernel_path, read_kernel
from neatskin.skin.model import SkinModel


def per_press_ms(model: SkinModel, x, y, depth) -> float:
    t0 = time.process_time()
    for i in range(x.shape[0]):
        model.pair_resistance_ohm(np.full(depth.shape[1], x[i]), np.full(depth.shape[1], y[i]), depth[i])
    return 1e3 * (time.process_time() - t0) / x.shape[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presses", type=int, default=300)
    parser.add_argument("--states", type=int, default=8, help="probe states per press (depths along the stroke)")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    layout = load_layout("protocols/skins/paper.toml")
    rng = np.random.default_rng(0)
    x, y = rng.uniform(1, 29, args.presses), rng.uniform(1, 29, args.presses)
    depth = np.linspace(0.5, 3.5, args.states)[None, :] + rng.normal(0, 0.2, (args.presses, 1))
    models = {
        "parametric": SkinModel(layout),
        "fe-kernel": SkinModel(layout, kernel=read_kernel(packaged_kernel_path())),
    }
    for model in models.values():
        per_press_ms(model, x[:20], y[:20], depth[:20])  # warm up
    times: dict[str, list[float]] = {name: [] for name in models}
    for _ in range(args.rounds):
        for name, model in models.items():
            times[name].append(per_press_ms(model, x, y, depth))
    load = os.getloadavg()
    print(f"{args.presses} presses x {args.states} states, CPU ms per press, load average {load[0]:.1f}")
    for name, values in times.items():
        print(f"  {name:<11s} median {np.median(values):.3f}  ({', '.join(f'{v:.3f}' for v in values)})")
    ratio = np.median(times["fe-kernel"]) / np.median(times["parametric"])
    print(f"  fe-kernel / parametric: {ratio:.2f}")


if __name__ == "__main__":
    main()

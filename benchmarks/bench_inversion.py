"""Benchmark: the physics inversion's CPU time against another checkout's, side by side (issue 27).

Usage:
    python benchmarks/bench_inversion.py DATASET --against DIR [--rounds N] [--reference] [--blas-threads N]

DATASET: a campaign folder, e.g. a paper dry run
(`neatskin campaign run protocols/paper.toml --dry-run --no-report -o RUN`); DIR: another checkout, e.g.
the base commit (`git -C /work/main worktree add --detach /tmp/base-invert 513ce57`).

Each checkout runs `skin_inversion` (as the report calls it: the dataset's layout, fidelity and probe) in a
child process with that checkout first on the path, alternating checkouts, --rounds times, on three row
sets: every press (what the report inverts, once, and cuts per repeat), and repeat 0's test rows of the
random and of the grouped split. Process CPU time (the inversion alone, after the dataset is read), the
best of the rounds, with the load average; the ratio column is against / this. It also prints, per row
set, the mean and median position error of each checkout, its model evaluations (rows through the model; since
the skin's analytic Jacobian a value with its gradient counts one, at ~1.5x a value's cost), and the distance between
the two checkouts' positions (the base's solver stops at its 40-step cap on most rows: see
docs/baselines.md). --reference adds a third column: this checkout's `method="reference"` (invref: the solver
before issue 27, at the same 40-step budget), in the same alternation. --blas-threads 1 runs every child on one
BLAS thread, as a report lane runs the inversion (the default leaves the library's default: this checkout's
`invert_presses` limits itself to one, older checkouts do not). --surrogate adds two more columns:
this checkout's `method="surrogate"` (issue 27's seventh round: the search on a tabulated spline of the model,
polished on the model) with its table cached ("surrogate", warm: the cache filled once before the rounds, not
timed) and built in the run ("surrogate cold": an empty cache folder for every child); the table rows a press are
printed beside the model rows.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
ROW_SETS = ("every press", "random test", "grouped test")


def _rows(dataset: str) -> dict[str, np.ndarray]:
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.evaluate import repeat_splits

    data = load_baseline_data(dataset)
    random_split, _ = repeat_splits("random", data.groups, 1, 0)
    grouped_split, _ = repeat_splits("grouped", data.groups, 1, 0)
    return {
        "every press": np.arange(len(data.y)),
        "random test": np.asarray(random_split[0].test),
        "grouped test": np.asarray(grouped_split[0].test),
    }


def here(dataset: str, row_set: str, out: str, method: str = "batched", blas_threads: int = 0) -> None:
    """In the child: invert one row set with the checkout on the path, write CPU s and the answers."""
    import time

    if blas_threads > 0:  # as a report lane runs it (tasks.py: cores // lanes threads, 1 on this machine)
        from threadpoolctl import threadpool_limits

        threadpool_limits(blas_threads)
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.inversion import skin_inversion

    data = load_baseline_data(dataset)
    rows = _rows(dataset)[row_set]
    started = time.process_time()
    res = skin_inversion(
        data.layout,
        data.X[rows],
        fidelity=data.skin_fidelity or "deformation",
        probe_radius_mm=data.probe_radius_mm or 2.75,
        method=method,
    )
    cpu_s = time.process_time() - started
    np.savez(
        out,
        cpu_s=cpu_s,
        xy_mm=res.xy_mm,
        depth_mm=res.depth_mm,
        y=data.y[rows],
        evals=res.n_model_evaluations,
        table_rows=getattr(res, "n_surrogate_evaluations", 0),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset")
    parser.add_argument("--against", type=Path, required=False)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--row-set", choices=ROW_SETS, nargs="*", default=list(ROW_SETS))
    parser.add_argument("--reference", action="store_true", help="also time this checkout's method='reference'")
    parser.add_argument("--surrogate", action="store_true", help="also time method='surrogate', warm and cold")
    parser.add_argument(
        "--blas-threads",
        type=int,
        default=0,
        help="BLAS threads in every child (0: the library's default, as a plain call gets; 1: as a report lane runs it)",
    )
    parser.add_argument("--here", nargs=3, metavar=("ROW_SET", "OUT", "METHOD"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.here:
        here(args.dataset, *args.here, blas_threads=args.blas_threads)
        return 0
    checkouts = {"this": REPO} | ({"against": args.against.resolve()} if args.against else {})
    checkouts |= {"reference": REPO} if args.reference else {}
    checkouts |= {"surrogate": REPO, "surrogate cold": REPO} if args.surrogate else {}
    methods = {"reference": "reference", "surrogate": "surrogate", "surrogate cold": "surrogate"}
    best: dict[tuple[str, str], float] = {}
    answers: dict[tuple[str, str], dict] = {}
    load = []
    with tempfile.TemporaryDirectory() as tmp:
        warm_cache = Path(tmp) / "warm-cache"
        if args.surrogate:  # the warm column's table, built once before the rounds (not timed)
            env = dict(os.environ, PYTHONPATH=str(REPO), NEATSKIN_CACHE=str(warm_cache))
            subprocess.run(
                [sys.executable, __file__, args.dataset, "--here", args.row_set[0], str(Path(tmp) / "warm.npz")]
                + ["surrogate", "--blas-threads", str(args.blas_threads)],
                env=env,
                check=True,
            )
        for round_ in range(args.rounds):
            order = list(checkouts.items())
            if round_ % 2:
                order.reverse()  # the first to run alternates too
            for row_set in args.row_set:
                for name, checkout in order:
                    out = str(Path(tmp) / f"{name}-{row_set.replace(' ', '_')}.npz")
                    env = dict(os.environ, PYTHONPATH=str(checkout))
                    if name == "surrogate":
                        env["NEATSKIN_CACHE"] = str(warm_cache)
                    elif name == "surrogate cold":
                        env["NEATSKIN_CACHE"] = tempfile.mkdtemp(dir=tmp)
                    method = methods.get(name, "batched")
                    subprocess.run(
                        [sys.executable, __file__, args.dataset, "--here", row_set, out, method]
                        + ["--blas-threads", str(args.blas_threads)],
                        env=env,
                        check=True,
                    )
                    load.append(os.getloadavg()[0])
                    with np.load(out) as z:
                        got = {k: z[k] for k in z.files}
                    key = (name, row_set)
                    best[key] = min(best.get(key, np.inf), float(got["cpu_s"]))
                    answers[key] = got
    threads = f"{args.blas_threads} BLAS thread(s)" if args.blas_threads else "BLAS threads as the library defaults"
    print(
        f"\ninversion CPU s, best of {args.rounds} round(s), {threads}; load average {min(load):.2f} to {max(load):.2f}"
    )
    others = [name for name in checkouts if name != "this"]
    print(f"{'rows':<13} {'n':>5} " + " ".join(f"{n + ' s':>15}" for n in checkouts) + " ratios (other / this)")
    for row_set in args.row_set:
        n = len(answers[("this", row_set)]["y"])
        cells = " ".join(f"{best[(name, row_set)]:>15.2f}" for name in checkouts)
        ratios = " ".join(f"{name} {best[(name, row_set)] / best[('this', row_set)]:.1f}x" for name in others)
        print(f"{row_set:<13} {n:>5} {cells} {ratios}")
    print(
        f"\n{'rows':<13} {'checkout':<14} {'mean err mm':>12} {'median mm':>10} {'<= 2.75 %':>10} {'evals/press':>12} "
        f"{'table/press':>12}"
    )
    summary = {}
    for row_set in args.row_set:
        for name in checkouts:
            a = answers[(name, row_set)]
            err = np.hypot(*(a["xy_mm"] - a["y"]).T)
            summary[f"{name} {row_set}"] = float(np.mean(err))
            print(
                f"{row_set:<13} {name:<14} {np.mean(err):>12.4f} {np.median(err):>10.4f} {100 * np.mean(err <= 2.75):>10.2f} "
                f"{float(a['evals']) / len(err):>12.1f} {float(a.get('table_rows', 0)) / len(err):>12.1f}"
            )
        for name in others:
            a, b = answers[("this", row_set)], answers[(name, row_set)]
            apart = np.max(np.abs(np.c_[a["xy_mm"], a["depth_mm"]] - np.c_[b["xy_mm"], b["depth_mm"]]), axis=1)
            q = np.quantile(apart, [0.5, 0.9, 0.99, 1.0])
            print(
                f"{'':<13} apart from {name} (largest coordinate, mm): median {q[0]:.2g}, 90 % {q[1]:.2g}, "
                f"99 % {q[2]:.2g}, max {q[3]:.2g}; within 1e-3 mm {100 * np.mean(apart < 1e-3):.1f} %, "
                f"> 0.1 mm {100 * np.mean(apart > 0.1):.1f} %"
            )
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

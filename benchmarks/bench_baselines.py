"""Benchmark: every baseline's error and fit time on a paper-sized dataset, and our LM loop against scipy's lm.

Usage:
    python benchmarks/bench_baselines.py [DATASET] [--scipy-max-nfev N] [--skip-scipy] [--seed S]
        [--report | --report-only] [--split both] [--against DIR] [--rounds N]

DATASET is a campaign folder (e.g. a dry run of protocols/paper.toml); without it a synthetic
2,800 x 28 table (100 positions x 28 repeats, see neatskin.skin.synthetic) is used.

Part 1: each model fit once on the paper's split (95 % + 3 % rows train, 2 % test) and once on a
grouped hold-out (20 % of positions); mean error and fit time.
Part 2 (targets: the LM network with 10 restarts fits in < 3 s with its restarts in processes,
and >= 10x faster than `scipy.optimize.least_squares(method="lm")` at equal or lower validation
loss): our 10-restart fit in one process and in --jobs processes (joblib), side by side in this
run, then restart 0's exact problem (same scaled rows, same start) solved by our loop alone and
by MINPACK (finite-difference Jacobian, as a plain least_squares call; and the analytic one).
Part 3 (--report, or --report-only): the whole report as the CLI makes it (`neatskin baselines
DATASET --split both`: 10 repeats, every split and model, the inversion), each run a child process:
wall time, CPU time (the command and the worker processes it waited for) and peak RSS (its largest
process), with the load average. With --against DIR the same report runs on another checkout
(e.g. the base commit: `git worktree add /tmp/base HEAD~3`) alternating with this one, --rounds
times (the first to run alternates too), and the table gives the wall-time ratio per round.

    python benchmarks/bench_baselines.py RUN --report-only --against /tmp/base --rounds 2

--timeline: the report's tasks in 2 processes, costliest first against the given order, alternating:
wall time, busy time and how long one worker sat idle at the end while the other finished.

--pieces: CPU time of the report's main-process pieces, the Fig. 9 ellipse figure (7 panels x
every position) and the inversion of every press, per checkout in a child, side by side.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sklearn.model_selection import GroupShuffleSplit

from neatskin.baselines.evaluate import paper_split
from neatskin.baselines.lm import LMNetworkRegressor, fit_with_scipy_lm
from neatskin.baselines.lmnetwork import forward, train_lm
from neatskin.baselines.metrics import position_errors
from neatskin.baselines.models import make_models

REPO = Path(__file__).resolve().parent.parent


def load(dataset: str | None):
    if dataset is None:
        from neatskin.layout import load_layout
        from neatskin.skin.synthetic import synthetic_presses

        df = synthetic_presses(
            load_layout(Path(__file__).resolve().parents[1] / "protocols/skins/paper.toml"),
            100,
            28,
            noise_ohm=1.0,
            seed=0,
        )
        return (
            "synthetic 100 positions x 28 repeats",
            df.filter(like="dR_ohm").to_numpy(),
            df[["x_mm", "y_mm"]].to_numpy(),
            df["position_id"].to_numpy(),
        )
    from neatskin.baselines.dataset import load_baseline_data

    data = load_baseline_data(dataset)
    return dataset, data.X, data.y, data.groups


def part_models(X, y, groups, seed):
    train, val, test = paper_split(len(y), seed)
    random_train = np.concatenate([train, val])
    g_train, g_test = next(GroupShuffleSplit(1, test_size=0.2, random_state=seed).split(X, y, groups))
    print(
        f"{'model':<13} {'fit s (paper split)':>20} {'err mm, random':>15} {'err mm, grouped':>16} {'pred us/row':>12}"
    )
    for name, model in make_models(random_state=seed, n_features=X.shape[1]).items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            model.fit(X[random_train], y[random_train])
            fit_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            pred = model.predict(X[test])
            pred_us = 1e6 * (time.perf_counter() - t0) / len(test)
            err_random = position_errors(y[test], pred).mean_error_mm
            model.fit(X[g_train], y[g_train])
            err_grouped = position_errors(y[g_test], model.predict(X[g_test])).mean_error_mm
        print(f"{name:<13} {fit_s:>20.3f} {err_random:>15.3f} {err_grouped:>16.3f} {pred_us:>12.1f}")


def part_lm_vs_scipy(X, y, seed, max_nfev, skip_scipy, jobs):
    train, val, test = paper_split(len(y), seed)
    rows = np.concatenate([train, val])
    LMNetworkRegressor(n_restarts=jobs, max_epochs=1, random_state=seed, n_jobs=jobs).fit(X[:50], y[:50])  # warm pool
    times = {}
    for n_jobs in (1, jobs):
        model = LMNetworkRegressor(random_state=seed, n_jobs=n_jobs)
        t0 = time.perf_counter()
        model.fit(X[rows], y[rows])
        times[n_jobs] = time.perf_counter() - t0
    fit10_s = times[jobs]
    print(
        f"\nLMNetworkRegressor, 10 restarts on {len(rows)} rows: fit {times[1]:.2f} s in 1 process, "
        f"{fit10_s:.2f} s in {jobs} processes (ratio {times[1] / fit10_s:.2f}x; target < 3 s), "
        f"epochs per restart {model.n_epochs_.tolist()}"
    )
    print(f"  validation MSE (scaled) per restart: min {model.val_mse_.min():.3e}, max {model.val_mse_.max():.3e}")

    p = model.restart_problem(X[rows], y[rows], restart=0)
    n_out = p["y_train"].shape[1]
    xs_test = (X[test] - model.x_min_) / model.x_span_
    ys_test = (y[test] - model.y_min_) / model.y_span_

    def test_mse(w):
        return float(np.mean((forward(w, xs_test, model.n_hidden, n_out)[1] - ys_test) ** 2))

    t0 = time.perf_counter()
    ours = train_lm(p["w0"], p["x_train"], p["y_train"], p["x_val"], p["y_val"], model.n_hidden)
    ours_s = time.perf_counter() - t0
    print(f"\nrestart 0's problem ({len(p['x_train'])} train rows, {len(p['x_val'])} val rows, same start):")
    print(f"{'solver':<34} {'time s':>8} {'train MSE':>10} {'val MSE':>10} {'test MSE':>10}")
    print(
        f"{'ours (trainlm loop), 1 restart':<34} {ours_s:>8.2f} {ours.train_mse:>10.3e} {ours.val_mse:>10.3e} "
        f"{test_mse(ours.weights):>10.3e}  ({ours.n_epochs} epochs, stop: {ours.stop_reason})"
    )
    best = model.val_mse_.min()
    print(f"{'ours, best of 10 restarts':<34} {fit10_s:>8.2f} {'':>10} {best:>10.3e} {test_mse(model.weights_):>10.3e}")
    if skip_scipy:
        return
    for analytic in (False, True):
        label = "scipy lm, " + ("analytic Jacobian" if analytic else "finite differences")
        ref = fit_with_scipy_lm(
            p["x_train"],
            p["y_train"],
            p["x_val"],
            p["y_val"],
            p["w0"],
            model.n_hidden,
            analytic_jacobian=analytic,
            max_nfev=max_nfev,
        )
        print(
            f"{label:<34} {ref.fit_time_s:>8.2f} {ref.train_mse:>10.3e} {ref.val_mse:>10.3e} "
            f"{test_mse(ref.weights):>10.3e}  ({ref.n_evaluations} evaluations)"
        )
        print(
            f"  ratio scipy time / ours: {ref.fit_time_s / ours_s:.1f}x per restart, "
            f"{ref.fit_time_s / fit10_s:.1f}x against our whole 10-restart fit; "
            f"val MSE ours(1) / scipy = {ours.val_mse / ref.val_mse:.2f}, "
            f"ours(best of 10) / scipy = {best / ref.val_mse:.2f} (on different validation rows)"
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", default=None)
    parser.add_argument("--scipy-max-nfev", type=int, default=None)
    parser.add_argument("--skip-scipy", action="store_true")
    parser.add_argument("--skip-models", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="processes for the LM restarts (default 2)")
    parser.add_argument("--report", action="store_true", help="also time the whole report on DATASET")
    parser.add_argument("--report-only", action="store_true", help="only the whole report (no parts 1 and 2)")
    parser.add_argument("--split", default="both", help="the report's --split (default both, as the main job)")
    parser.add_argument("--against", type=Path, help="another checkout: its report measured side by side")
    parser.add_argument("--rounds", type=int, default=1, help="alternating report rounds per checkout")
    parser.add_argument("--pieces", action="store_true", help="only the ellipse figure and the inversion (CPU s)")
    parser.add_argument("--pieces-here", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--timeline", action="store_true", help="only the task order: idle worker time at the end")
    args = parser.parse_args(argv)
    if args.timeline:
        part_timeline(args.dataset, args.rounds)
        return 0
    if args.pieces_here:
        pieces_here(args.dataset)
        return 0
    if args.pieces:
        part_pieces(args.dataset, args.against, args.rounds)
        return 0
    if args.report_only:
        if not args.dataset:
            parser.error("--report-only needs DATASET")
        part_report(args.dataset, args.split, args.against, args.rounds)
        return 0
    label, X, y, groups = load(args.dataset)
    print(f"dataset: {label}: {X.shape[0]} presses x {X.shape[1]} features, {len(np.unique(groups))} positions")
    if not args.skip_models:
        part_models(X, y, groups, args.seed)
    part_lm_vs_scipy(X, y, args.seed, args.scipy_max_nfev, args.skip_scipy, args.jobs)
    if args.report and args.dataset:
        part_report(args.dataset, args.split, args.against, args.rounds)
    return 0


def pieces_here(dataset: str) -> None:
    """CPU time of the report's main-process pieces in this process: Fig. 9 ellipses and the inversion."""
    import tempfile

    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.evaluate import ModelResult
    from neatskin.baselines.inversion import skin_inversion
    from neatskin.baselines.metrics import position_errors
    from neatskin.baselines.plots import plot_error_ellipses

    data = load_baseline_data(dataset)
    rng = np.random.default_rng(0)
    results = []
    for i in range(7):  # the grouped split's panels: 7 models, every position once
        pred = data.y + rng.normal(0.0, 1.5, data.y.shape)
        pe = position_errors(data.y, pred)
        results.append(ModelResult(f"m{i}", "grouped", (pe,), 0.1, 1e-5, len(pred), data.y, pred, data.groups))
    with tempfile.TemporaryDirectory() as tmp:
        plot_error_ellipses(results[:1], Path(tmp) / "warm.png", data.layout)
        ellipses = []
        for _ in range(3):
            t0 = time.process_time()
            plot_error_ellipses(results, Path(tmp) / "ellipses.png", data.layout)
            ellipses.append(time.process_time() - t0)
    t0 = time.process_time()
    skin_inversion(data.layout, data.X, fidelity=data.skin_fidelity or "deformation")
    inversion = time.process_time() - t0
    print(f"{min(ellipses):.3f} {inversion:.3f}")


def part_pieces(dataset: str, against: Path | None, rounds: int) -> None:
    """The ellipse figure and the inversion, each checkout in a child process, alternating."""
    checkouts = {"this": REPO} | ({"against": against.resolve()} if against is not None else {})
    best: dict[str, list[float]] = {}
    for _ in range(rounds):
        for name, checkout in checkouts.items():
            env = dict(os.environ, PYTHONPATH=str(checkout))
            out = subprocess.run(
                [sys.executable, __file__, dataset, "--pieces-here"],
                env=env,
                capture_output=True,
                text=True,
                check=True,
            )
            values = [float(v) for v in out.stdout.split()[-2:]]
            best[name] = [min(a, b) for a, b in zip(best.get(name, values), values)]
    print(
        f"\nreport pieces, CPU s (best of {rounds} round(s); ellipses best of 3 draws), load {os.getloadavg()[0]:.2f}"
    )
    print(f"{'checkout':<9} {'Fig. 9 ellipses, 7 x 100 positions':>36} {'inversion, every press':>24}")
    for name, (ell, inv) in best.items():
        print(f"{name:<9} {ell:>36.2f} {inv:>24.2f}")
    if against is not None:
        (e1, i1), (e0, i0) = best["this"], best["against"]
        print(f"{'ratio':<9} {e1 / e0:>35.2f}x {i1 / i0:>23.2f}x")


def _timed(func, args):
    """A task's output with its start, end (epoch s) and worker pid."""
    started = time.time()
    out = func(*args)
    return out, started, time.time(), os.getpid()


def part_timeline(dataset: str, rounds: int) -> None:
    """The report's tasks (every fit and the inversion) in 2 processes, costliest first and in the given
    order, alternating: per order the wall time and how long a worker sat idle while the other finished."""
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.evaluate import fit_tasks, repeat_splits
    from neatskin.baselines.inversion import skin_inversion
    from neatskin.baselines.models import INVERSION_COST_S_PER_PRESS, MODEL_NAMES, fit_cost_s
    from neatskin.baselines.tasks import Task, run_tasks

    data = load_baseline_data(dataset)
    reps = {s: repeat_splits(s, data.groups, 10)[0] for s in ("grouped", "random", "design")}
    rows = int(np.mean([len(r.train) for rr in reps.values() for r in rr]))
    models = make_models(MODEL_NAMES, n_rows=rows, lm_restarts=1)
    tasks = fit_tasks(models, data.X, data.y, data.groups, reps, {n: fit_cost_s(n, rows) for n in MODEL_NAMES})
    inversion = (data.layout, data.X, data.skin_fidelity or "deformation", 2.75)
    tasks.append(Task(("inversion",), INVERSION_COST_S_PER_PRESS * len(data.y), skin_inversion, inversion))
    print(f"\nthe report's {len(tasks)} tasks in 2 processes, {rounds} alternating round(s)")
    print(f"{'order':<16} {'wall s':>7} {'busy s':>7} {'one worker idle at the end, s':>30}  load")
    for r in range(rounds):
        for order in ("costliest first", "given order") if r % 2 == 0 else ("given order", "costliest first"):
            cost = (lambda t: t.cost_s) if order == "costliest first" else (lambda t: 0.0)
            timed = [Task(t.key, cost(t), _timed, (t.func, t.args)) for t in tasks]
            t0 = time.time()
            out = run_tasks(timed, n_jobs=2)
            wall = time.time() - t0
            ends: dict[int, float] = {}
            busy = 0.0
            for _, started, ended, pid in out.values():
                ends[pid] = max(ends.get(pid, 0.0), ended)
                busy += ended - started
            idle = max(ends.values()) - min(ends.values())
            print(f"{order:<16} {wall:>7.1f} {busy:>7.1f} {idle:>30.2f}  {os.getloadavg()[0]:.1f}")


@dataclass(frozen=True)
class ReportRun:
    wall_s: float
    cpu_s: float  # the command and every process it waited for (joblib's workers)
    peak_rss_mb: float  # the largest single process of them
    ok: bool


def run_report(checkout: Path, dataset: str, split: str, out: Path) -> ReportRun:
    """`neatskin baselines DATASET --split SPLIT` as a child with `checkout` first on the import path."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    argv = [sys.executable, "-m", "neatskin", "baselines", dataset, "--split", split, "--out", str(out)]
    started = time.perf_counter()
    child = subprocess.Popen([*argv, "--no-progress"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - started
    code = os.waitstatus_to_exitcode(status)
    err = child.stderr.read().decode(errors="replace") if child.stderr else ""
    if child.stderr:
        child.stderr.close()
    if code != 0:
        print(f"  ! {checkout}: exit {code}: {err.strip()[-400:]}", file=sys.stderr)
    return ReportRun(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, code == 0)


def part_report(dataset: str, split: str, against: Path | None, rounds: int) -> None:
    """The whole report as the CLI makes it, wall / CPU / peak RSS, alternating with another checkout."""
    checkouts = {"this": REPO}
    if against is not None:
        checkouts["against"] = against.resolve()
    runs: dict[str, list[ReportRun]] = {name: [] for name in checkouts}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            # who goes first alternates: on a shared machine the load drifts, and the second run of a round would
            # otherwise always meet a different load than the first
            order = list(checkouts.items()) if r % 2 == 0 else list(reversed(checkouts.items()))
            for name, checkout in order:
                runs[name].append(run_report(checkout, dataset, split, Path(tmp) / f"{name}-{r}"))
    load_after = os.getloadavg()
    print(
        f"\nwhole report, `neatskin baselines {dataset} --split {split}` (10 repeats, every model, the inversion), "
        f"{os.cpu_count()} cores, {rounds} alternating round(s); load average before "
        f"{load_before[0]:.2f}, after {load_after[0]:.2f}"
    )
    header = f"{'checkout':<9} {'round':>5} {'wall s':>8} {'CPU s':>8} {'peak RSS MB':>12} {'ok':>4}"
    print(header + (f" {'wall this/against':>18}" if against else ""))
    for r in range(rounds):
        for name in checkouts:
            m = runs[name][r]
            line = (
                f"{name:<9} {r:>5} {m.wall_s:>8.1f} {m.cpu_s:>8.1f} {m.peak_rss_mb:>12.0f} {'yes' if m.ok else 'NO':>4}"
            )
            if against and name == "this":
                line += f" {m.wall_s / runs['against'][r].wall_s:>17.2f}x"
            print(line)
    for name in checkouts:
        walls = sorted(m.wall_s for m in runs[name])
        print(f"{name:<9} median wall {walls[len(walls) // 2]:.1f} s, best {walls[0]:.1f} s ({checkouts[name]})")


if __name__ == "__main__":
    sys.exit(main())

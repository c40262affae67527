"""Benchmark: position error (mm) against run time and data, as curves: parquet + PNG.

Usage:
    python benchmarks/bench_curves.py [--out FOLDER] [--dataset CAMPAIGN] [--repeats R] [--jobs J] [--quick]

Three studies, each point the mean error over R grouped (seed, split) repeats with its 95 %
interval (cut at zero), and the mean fit time per fit:
1. learners against fit time: LM epochs and restarts, MLP width, k of kNN, number of trees,
   on DATASET (a campaign folder, e.g. a dry run of protocols/paper.toml) or on a synthetic
   2,800-press table;
2. learning curves: 25 to 400 positions at a fixed budget of 2,800 presses (repeats = 2800 /
   positions), on synthetic presses through the skin model;
3. the scene's knobs: error against the probe placement error (sd, mm) and the measurement
   noise (sd, ohm) of a skin-model scene, learned models beside the physics inversion.
   (The realistic `paper-like` scene does not exist in this worktree; these are the knobs
   that do: SkinModel.placement_error_mm and additive noise on dR.)

Writes curves.parquet and curves.png in --out (default: benchmarks/out).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.baselines.evaluate import evaluate_models, repeat_splits, result_from_predictions
from neatskin.baselines.lm import LMNetworkRegressor
from neatskin.baselines.models import make_model
from neatskin.layout import load_layout

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "protocols" / "skins" / "paper.toml"


def skin_scene(n_positions: int, repeats: int, seed: int, placement_mm: float = 0.0, noise_ohm: float = 0.1):
    """Presses through SkinModel (deformation): commanded positions are the labels, the probe lands
    placement_mm (sd per axis) off, dR gets Gaussian noise of noise_ohm; depth 3.5 mm."""
    from neatskin.skin.model import SkinModel, placement_error_mm
    from neatskin.skin.synthetic import synthetic_positions_mm

    layout = load_layout(LAYOUT)
    skin = SkinModel(layout)
    rng = np.random.default_rng([seed, 7])
    xy = synthetic_positions_mm(layout, n_positions, seed)
    commanded = np.repeat(xy, repeats, axis=0)
    x, y = placement_error_mm(commanded[:, 0], commanded[:, 1], placement_mm, rng)
    dr = skin.pair_resistance_ohm(x, y, 3.5) - skin.baseline_pair_resistance_ohm
    dr = dr + rng.normal(0.0, noise_ohm, dr.shape)
    return layout, dr, commanded, np.repeat(np.arange(n_positions), repeats)


def _rows(study, knob, value, results, extra=None):
    out = []
    for r in results:
        s = r.summary["mean_error_mm"]
        out.append(
            {
                "study": study,
                "knob": knob,
                "value": float(value),
                "model": r.model,
                "fit_time_s": r.fit_time_s + r.predict_time_per_sample_s * r.per_repeat[0].n,
                "mean_error_mm": s.mean,
                "lo_mm": max(s.low, 0.0),
                "hi_mm": s.high,
                "median_error_mm": r.summary["median_error_mm"].mean,
                "n_repeats": r.n_repeats,
                **(extra or {}),
            }
        )
    return out


def study_learners(X, y, groups, repeats, jobs, quick):
    reps, _ = repeat_splits("grouped", groups, repeats, 0, 5)
    sweeps = {
        "LM epochs (1 restart)": (
            "max_epochs",
            [2, 5, 20, 100] if quick else [2, 5, 10, 20, 50, 1000],
            lambda v: LMNetworkRegressor(n_restarts=1, max_epochs=int(v), random_state=0),
        ),
        "LM restarts": (
            "n_restarts",
            [1, 3] if quick else [1, 3, 10],
            lambda v: LMNetworkRegressor(n_restarts=int(v), random_state=0),
        ),
        "MLP width (2 layers)": ("width", [8, 32] if quick else [8, 16, 32, 64, 128], None),
        "kNN k": ("k", [1, 30, 100] if quick else [1, 5, 30, 60, 100, 200], None),
        "extra trees": ("n_estimators", [10, 100] if quick else [10, 30, 100, 300], None),
    }
    rows = []
    for label, (knob, values, factory) in sweeps.items():
        for v in values:
            if factory is not None:
                est = factory(v)
            elif knob == "width":
                est = make_model("mlp")
                est.set_params(transformedtargetregressor__regressor__hidden_layer_sizes=(int(v), int(v)))
            elif knob == "k":
                est = make_model("knn")
                est.set_params(kneighborsregressor__n_neighbors=int(v))
            else:
                est = make_model("extra_trees")
                est.set_params(n_estimators=int(v))
            res = evaluate_models({label: est}, X, y, groups, {"grouped": reps}, n_jobs=jobs)
            rows += _rows("learners", knob, v, res)
            print(
                f"  {label:<22} {knob}={v:<6} fit {rows[-1]['fit_time_s']:.3g} s  error {rows[-1]['mean_error_mm']:.3g} mm"
            )
    return rows


def study_learning_curve(repeats, jobs, quick, budget=2800):
    rows = []
    for n_pos in [25, 100, 400] if quick else [25, 50, 100, 200, 400]:
        per = budget // n_pos
        _, X, y, groups = skin_scene(n_pos, per, seed=1)
        reps, _ = repeat_splits("grouped", groups, repeats, 0, 5)
        models = {n: make_model(n, n_rows=len(y), lm_restarts=1) for n in ("ridge", "knn", "mlp", "lm_network")}
        res = evaluate_models(models, X, y, groups, {"grouped": reps}, n_jobs=jobs)
        rows += _rows("learning curve", "positions", n_pos, res, {"presses_per_position": per})
        print(
            f"  {n_pos} positions x {per}: "
            + ", ".join(f"{r.model} {r.summary['mean_error_mm'].mean:.2f}" for r in res)
        )
    return rows


def study_knobs(repeats, jobs, quick):
    from neatskin.baselines.inversion import skin_inversion

    rows = []
    knobs = {
        "placement_mm": [0.0, 0.5, 2.0] if quick else [0.0, 0.1, 0.25, 0.5, 1.0, 2.0],
        "noise_ohm": [0.1, 10.0] if quick else [0.01, 0.1, 1.0, 10.0, 100.0],
    }
    for knob, values in knobs.items():
        for v in values:
            kwargs = {knob: v}
            layout, X, y, groups = skin_scene(100, 10, seed=2, **kwargs)
            reps, _ = repeat_splits("grouped", groups, repeats, 0, 5)
            models = {n: make_model(n, n_rows=len(y), lm_restarts=1) for n in ("knn", "mlp", "lm_network")}
            res = evaluate_models(models, X, y, groups, {"grouped": reps}, n_jobs=jobs)
            inv = skin_inversion(layout, X)
            res.append(result_from_predictions("inversion", "grouped", reps, inv.xy_mm, y, groups, inv.time_s / len(y)))
            rows += _rows("scene knobs", knob, v, res)
            print(f"  {knob}={v}: " + ", ".join(f"{r.model} {r.summary['mean_error_mm'].mean:.3g}" for r in res))
    return rows


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 9.5))
    learners = table[table.study == "learners"]
    ax = axes[0, 0]
    for i, (model, g) in enumerate(learners.groupby("model", sort=False)):
        g = g.sort_values("fit_time_s")
        ax.errorbar(
            g.fit_time_s,
            g.mean_error_mm,
            yerr=[g.mean_error_mm - g.lo_mm.clip(lower=g.mean_error_mm * 1e-2), g.hi_mm - g.mean_error_mm],
            fmt="o-",
            color=f"C{i}",
            capsize=2,
            label=f"{model} ({g.knob.iloc[0]})",
        )
        for j, point in enumerate(g.itertuples(index=False)):  # each point's knob value, alternately above/below
            ax.annotate(
                f"{point.value:g}",
                (point.fit_time_s, point.mean_error_mm),
                fontsize=6.5,
                color=f"C{i}",
                xytext=(3, 5 if j % 2 == 0 else -10),
                textcoords="offset points",
            )
    ax.set(xscale="log", yscale="log", xlabel="time per fit + predict (s, log)", ylabel="mean error (mm, log)")
    ax.set_title("Learners against fit time (grouped split); numbers: the knob's value", fontsize=10)
    ax.legend(fontsize=7)
    ax = axes[0, 1]
    curve = table[table.study == "learning curve"]
    for i, (model, g) in enumerate(curve.groupby("model", sort=False)):
        lo = g.lo_mm.clip(lower=g.mean_error_mm * 1e-2)  # log axis: a bar reaching 0 is drawn to 1 % of the mean
        ax.errorbar(
            g.value,
            g.mean_error_mm,
            yerr=[g.mean_error_mm - lo, g.hi_mm - g.mean_error_mm],
            fmt="o-",
            color=f"C{i}",
            capsize=2,
            label=model,
        )
    ax.set(xscale="log", yscale="log", xlabel="positions (log), 2,800 presses in all", ylabel="mean error (mm, log)")
    ax.set_xticks(sorted(curve.value.unique()), [f"{v:g}" for v in sorted(curve.value.unique())])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_title("Learning curve at a fixed press budget (new positions)", fontsize=10)
    ax.legend(fontsize=7)
    for ax, knob, label in (
        (axes[1, 0], "placement_mm", "probe placement error, sd per axis (mm)"),
        (axes[1, 1], "noise_ohm", "measurement noise on dR, sd (ohm, log)"),
    ):
        sub = table[(table.study == "scene knobs") & (table.knob == knob)]
        for i, (model, g) in enumerate(sub.groupby("model", sort=False)):
            x = g.value.replace(0.0, np.nan) if knob == "noise_ohm" else g.value
            ax.errorbar(
                x,
                g.mean_error_mm,
                yerr=[g.mean_error_mm - g.lo_mm, g.hi_mm - g.mean_error_mm],
                fmt="o-",
                color=f"C{i}",
                capsize=2,
                label=model,
            )
        if knob == "noise_ohm":
            ax.set_xscale("log")
        ax.set(xlabel=label, ylabel="mean error (mm)", ylim=(0, None))
        ax.set_title(f"Error against the scene's {knob.replace('_', ' ')} (grouped split)", fontsize=10)
        ax.legend(fontsize=7)
    for ax in axes.ravel():
        ax.grid(True, which="major", alpha=0.3)
    fig.suptitle(
        "Position error: mean over grouped repeats, bars: 95 % interval of the mean (cut at zero)", fontsize=11
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "out"))
    parser.add_argument("--dataset", default=None, help="campaign folder for the learners study (default synthetic)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="fewer points per curve")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("ignore")
    started = time.perf_counter()
    if args.dataset:
        from neatskin.baselines.dataset import load_baseline_data

        data = load_baseline_data(args.dataset)
        X, y, groups, label = data.X, data.y, data.groups, args.dataset
    else:
        _, X, y, groups = skin_scene(100, 28, seed=0)
        label = "skin-model scene, 100 positions x 28 presses"
    print(f"1. learners against fit time on {label}")
    rows = study_learners(X, y, groups, args.repeats, args.jobs, args.quick)
    print("2. learning curve at 2,800 presses")
    rows += study_learning_curve(args.repeats, args.jobs, args.quick)
    print("3. scene knobs")
    rows += study_knobs(args.repeats, args.jobs, args.quick)
    table = pd.DataFrame(rows)
    table.to_parquet(out / "curves.parquet", index=False)
    plot(table, out / "curves.png")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"wrote {out / 'curves.parquet'} and {out / 'curves.png'} in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The README's comparison with the paper from full main jobs, over campaign seeds: each seed is the whole
`neatskin campaign run protocols/paper.toml --dry-run` (pty printer, driver, recorder, writer, and the default
baseline report), with only `[campaign] seed` changed; then the figures are read back from each run's report table
(baselines.csv) and dataset.

    python benchmarks/paper_dry_runs.py [--seeds 2019 1 2 3 4] [--jobs 2] [--out out/paper-dry-runs]
    python benchmarks/paper_dry_runs.py --collect-only --out out/paper-dry-runs    # tables from finished runs

Per seed it prints: the report's LM network on the random 95/3/2 split (mean error, share within the probe radius,
MSE per coordinate; mean over the report's 10 repeats); the paper's pairing on the same dataset (one fixed test set of
11 positions x 6 presses, 10 LM networks each with its own random validation rows: their average and the one with the
lowest test MSE, `neatskin.baselines.paperpairing`); the grouped
split (new positions) of extra trees, k-NN, the physics inversion and the LM network; the label-noise floors of the
two splits; the presses kept with a cut pair. Then mean +- std over the seeds (ddof 1).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
GROUPED_MODELS = ("extra_trees", "knn", "inversion", "lm_network")


def seeded_protocol(seed: int, folder: Path) -> Path:
    """protocols/paper.toml with its campaign seed set, in `folder`, its [files] resolved through symlinks."""
    folder.mkdir(parents=True, exist_ok=True)
    for sub in ("skins", "wiring", "printers"):
        link = folder / sub
        if not link.exists():
            link.symlink_to(REPO / "protocols" / sub)
    text = (REPO / "protocols" / "paper.toml").read_text()
    text, n = re.subn(r"(?m)^seed = \d+", f"seed = {seed}", text)
    if n != 1:
        raise SystemExit("protocols/paper.toml: expected one `seed = N` line in [campaign]")
    path = folder / f"paper_seed{seed}.toml"
    path.write_text(text)
    return path


def run_one(seed: int, out: Path) -> tuple[int, float]:
    run_dir = out / f"seed{seed}"
    if (run_dir / "baselines.csv").exists():
        return seed, float("nan")
    proto = seeded_protocol(seed, out / "protocols")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    started = time.perf_counter()
    cmd = [sys.executable, "-m", "neatskin.cli", "campaign", "run", str(proto), "--dry-run", "-q", "-o", str(run_dir)]
    with open(out / f"seed{seed}.log", "w") as log:
        subprocess.run(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, check=True, cwd=REPO)
    return seed, time.perf_counter() - started


def collect(seed: int, run_dir: Path) -> dict:
    import pandas as pd

    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.paperpairing import paired_statistics

    table = pd.read_csv(run_dir / "baselines.csv").set_index(["model", "split"])
    lm = table.loc[("lm_network", "random")]
    data = load_baseline_data(run_dir)
    paired = paired_statistics(data.X, data.y, data.groups, seed)
    row = {
        "lm_random_mm": lm["mean_error_mm"],
        "lm_random_within_pct": lm["within_probe_pct"],
        "lm_random_mse_coord": lm["mse_per_coordinate_mm2"],
        "avg10_mm": paired["avg_mean_mm"],
        "best10_mm": paired["best_mean_mm"],
        "avg10_mse_coord": paired["avg_mse_coord_mm2"],
        "best10_mse_coord": paired["best_mse_coord_mm2"],
        "best10_within_pct": 100 * paired["best_within"],
        "bestval10_mm": paired["bestval_mean_mm"],
        "floor_random_mm": table.loc[("lm_network", "random")]["label_floor_mean_mm"],
        "floor_grouped_mm": table.loc[("lm_network", "grouped")]["label_floor_mean_mm"],
        "cut_pct": 100 * data.n_saturated / len(data.X),
    }
    if ("lm_network", "design") in table.index:  # the paper's scored test: 11 positions x 6 presses
        design = table.loc[("lm_network", "design")]
        row |= {
            "lm_design_mm": design["mean_error_mm"],
            "lm_design_within_pct": design["within_probe_pct"],
            "lm_design_mse_coord": design["mse_per_coordinate_mm2"],
            "lm_design_best_mm": design.get("best_mean_error_mm", np.nan),
            "lm_design_best_within_pct": design.get("best_within_probe_pct", np.nan),
        }
    for model in GROUPED_MODELS:
        row[f"{model}_grouped_mm"] = table.loc[(model, "grouped")]["mean_error_mm"]
        row[f"{model}_grouped_within_pct"] = table.loc[(model, "grouped")]["within_probe_pct"]
    return {k: float(v) for k, v in row.items()}


def print_tables(rows: dict[int, dict]) -> None:
    seeds = list(rows)
    cells = {k: np.array([rows[s][k] for s in seeds]) for k in rows[seeds[0]]}

    def line(label: str, keys: list[str], fmt: str) -> None:
        out = [label]
        if any(k not in cells for k in keys):  # a row that only some runs have (the design split)
            return
        for k in keys:
            v = cells[k]
            out.append(" / ".join(format(x, fmt) for x in v) + f" (**{v.mean():{fmt}} +- {v.std(ddof=1):{fmt}}**)")
        print("| " + " | ".join(out) + " |")

    print(f"campaign seeds {seeds}; per seed, then (mean +- std over seeds)")
    print("| statistic | value |\n|---|---|")
    for label, key, fmt in (
        ("LM random split (report, 10 repeats): mean error mm", "lm_random_mm", ".2f"),
        ("LM random split: within 2.75 mm %", "lm_random_within_pct", ".1f"),
        ("LM random split: MSE per coordinate mm^2", "lm_random_mse_coord", ".2f"),
        ("paper pairing (fixed 11 x 6 test), average of 10 networks: mean error mm", "avg10_mm", ".2f"),
        ("paper pairing, average of 10 networks: MSE per coordinate mm^2", "avg10_mse_coord", ".2f"),
        ("paper pairing, best of 10 (lowest test MSE): mean error mm", "best10_mm", ".2f"),
        ("paper pairing, best of 10: MSE per coordinate mm^2", "best10_mse_coord", ".2f"),
        ("paper pairing, best of 10: within 2.75 mm %", "best10_within_pct", ".1f"),
        ("paper pairing, lowest validation MSE instead: mean error mm", "bestval10_mm", ".2f"),
        ("LM design split (11 x 6, the paper's scored test): mean error mm", "lm_design_mm", ".2f"),
        ("LM design split: within 2.75 mm %", "lm_design_within_pct", ".1f"),
        ("LM design split: MSE per coordinate mm^2", "lm_design_mse_coord", ".2f"),
        ("LM design split, best network (lowest test MSE): mean error mm", "lm_design_best_mm", ".2f"),
        ("LM design split, best network: within 2.75 mm %", "lm_design_best_within_pct", ".1f"),
        *((f"grouped split (new positions), {m}: mean error mm", f"{m}_grouped_mm", ".2f") for m in GROUPED_MODELS),
        *((f"grouped split, {m}: within 2.75 mm %", f"{m}_grouped_within_pct", ".1f") for m in GROUPED_MODELS),
        ("label-noise floor, random split: mean mm", "floor_random_mm", ".2f"),
        ("label-noise floor, grouped split: mean mm", "floor_grouped_mm", ".2f"),
        ("presses kept with a cut pair %", "cut_pct", ".1f"),
    ):
        line(label, [key], fmt)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[2019, 1, 2, 3, 4])
    parser.add_argument("--jobs", type=int, default=2, help="campaigns at once")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "paper-dry-runs")
    parser.add_argument("--collect-only", action="store_true")
    args = parser.parse_args()
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    if not args.collect_only:
        load0 = os.getloadavg()[0]
        with ThreadPoolExecutor(args.jobs) as pool:
            for seed, wall in pool.map(lambda s: run_one(s, out), args.seeds):
                print(f"seed {seed}: main job {wall:.0f} s wall (load {load0:.1f} -> {os.getloadavg()[0]:.1f})")
    rows = {s: collect(s, out / f"seed{s}") for s in args.seeds if (out / f"seed{s}" / "baselines.csv").exists()}
    if rows:
        print_tables(rows)


if __name__ == "__main__":
    main()

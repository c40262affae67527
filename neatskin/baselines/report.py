"""The baseline report: evaluate every model on a dataset, print the table, write report.md, CSV, parquet, PNGs.

`run_baselines(dataset, split, models, out)` is what the CLI and the campaign runner call.
The table sets each model's error beside its fit and predict time; when the dataset folder
holds `physical_limit.parquet` (Cramér-Rao bound per position, from the dry run) the
table also gives each model's RMS error against the RMS bound.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.baselines.dataset import PHYSICAL_LIMIT_NAME, BaselineData, load_baseline_data
from neatskin.baselines.evaluate import PAPER_FRACTIONS, SPLITS, ModelResult, evaluate_model
from neatskin.baselines.models import DESCRIPTIONS, MODEL_NAMES, make_models
from neatskin.errors import DataError

PAPER_REAL_SKIN = {"mean_error_mm": 2.03, "std_error_mm": 0.26, "mse_mm2": 3.32, "within_probe_pct": 82.0}
TABLE_NAME = "baselines"


@dataclass(frozen=True)
class Report:
    """What run_baselines produced: results, the table, the bound, the text and the files written."""

    results: tuple[ModelResult, ...]
    table: pd.DataFrame
    bound_rms_mm: float | None
    text: str
    files: dict[str, Path] = field(default_factory=dict)


def bound_rms_mm(limit: pd.DataFrame | None) -> float | None:
    """Pooled RMS bound sqrt(mean crb^2) over the positions (inf if any position is unobservable)."""
    if limit is None or len(limit) == 0:
        return None
    crb = limit["crb_mm"].to_numpy(dtype=float)
    return float(np.sqrt(np.mean(crb * crb)))


def results_table(results: Iterable[ModelResult], bound: float | None) -> pd.DataFrame:
    table = pd.DataFrame([r.row() for r in results])
    table.insert(7, "rms_error_mm", np.sqrt(table["mse_mm2"]))
    if bound is not None:
        table["crb_rms_mm"] = bound
        table["rms_over_crb"] = table["rms_error_mm"] / bound if bound > 0 else np.inf
    return table


def format_table(table: pd.DataFrame) -> str:
    """A fixed-width text table, one row per model and split."""
    header = (
        f"{'model':<13} {'split':<8} {'mean err mm':>14} {'median':>7} {'RMS mm':>7} {'MSE mm2':>8} {'MSE/coord':>9} "
        f"{'<=2.75mm':>8} {'fit s':>8} {'pred us/row':>11}"
    )
    if "rms_over_crb" in table.columns:
        header += f" {'RMS/CRB':>8}"
    lines = [header, "-" * len(header)]
    for row in table.itertuples(index=False):
        line = (
            f"{row.model:<13} {row.split:<8} {row.mean_error_mm:>6.2f} ± {row.std_error_mm:<5.2f} "
            f"{row.median_error_mm:>7.2f} {row.rms_error_mm:>7.2f} {row.mse_mm2:>8.2f} {row.mse_per_coordinate_mm2:>9.2f} "
            f"{row.within_probe_pct:>7.1f}% {row.fit_time_s:>8.3f} {row.predict_time_per_sample_us:>11.1f}"
        )
        if "rms_over_crb" in table.columns:
            line += f" {row.rms_over_crb:>8.2f}"
        lines.append(line)
    return "\n".join(lines)


def _markdown(
    data: BaselineData,
    table: pd.DataFrame,
    bound: float | None,
    splits: tuple[str, ...],
    files: dict[str, Path],
    random_state: int | None,
) -> str:
    t, v, s = (int(100 * f) for f in PAPER_FRACTIONS)
    lines = [
        "# Baseline report",
        "",
        f"Dataset: `{data.source}`: {len(data.y)} presses at {len(np.unique(data.groups))} positions, "
        f"{data.X.shape[1]} pair features; {data.n_flagged_dropped} flagged presses dropped. Seed {random_state}.",
        "",
        "Splits:",
    ]
    if "grouped" in splits:
        lines.append(
            "- `grouped`: k-fold over positions (no position in both training and test rows); every press "
            "is predicted once, by the model that never saw its position. This is the honest error for a new press position."
        )
    if "random" in splits:
        lines.append(
            f"- `random`: the paper's split by row, {t} % train / {v} % validation / {s} % test; models fit on "
            "train + validation (the LM network holds out its own 3/98 for early stopping and restart choice). "
            "Repeats of a test position are in training, so this error is optimistic."
        )
    lines += [
        "",
        "Columns: mean Euclidean error ± its std (mm); median Euclidean error (mm; robust to a few wild extrapolations); RMS error = sqrt(MSE); `MSE mm2` = mean of dx²+dy²; "
        "`MSE/coord` = MATLAB's `mse` over both coordinates (half of it; the paper's 3.32 mm² is most likely this "
        "convention); `<=2.75mm` = share of predictions within the probe radius; fit time per fit (s); predict time per press (µs).",
        "",
        "```",
        format_table(table),
        "```",
        "",
    ]
    if bound is not None:
        lines += [
            f"Physical limit (`{PHYSICAL_LIMIT_NAME}`): the Cramér-Rao bound on the RMS position error, pooled over "
            f"positions as sqrt(mean CRB²) = {bound:.3f} mm. `RMS/CRB` says how far each model is from the best any "
            "unbiased estimator could do on this simulated skin and noise.",
            "",
        ]
    lines += [
        "For comparison, the paper on its real skin (28-5-2 network, random 95/3/2 split, 11 test positions x 6 presses): "
        f"mean error {PAPER_REAL_SKIN['mean_error_mm']} mm (std {PAPER_REAL_SKIN['std_error_mm']} mm as reported), "
        f"MSE {PAPER_REAL_SKIN['mse_mm2']} mm² averaged over ten models, {PAPER_REAL_SKIN['within_probe_pct']:.0f} % of "
        "predictions within the probe radius. Nothing here is tuned to match those figures.",
        "",
        "Models:",
        *[f"- `{name}`: {DESCRIPTIONS[name]}" for name in table["model"].unique()],
        "",
        "Files:",
        *[f"- {label}: `{path.name}`" for label, path in files.items()],
        "",
    ]
    return "\n".join(lines)


def run_baselines(
    dataset_folder: str | Path,
    split: str | Iterable[str] = "grouped",
    models: Iterable[str] | None = None,
    out: str | Path | None = None,
    *,
    flagged: str = "drop",
    random_state: int | None = 0,
    n_splits: int = 5,
    progress: bool = True,
    echo: bool = True,
) -> Report:
    """Evaluate the baselines on a dataset, print the table, and write report.md, CSV, parquet and PNGs.

    split: "grouped", "random", "both" or a list of them. models: names from MODEL_NAMES (all by default).
    out: folder for the outputs (the dataset folder by default).
    """
    from tqdm.auto import tqdm

    from neatskin.baselines.plots import plot_error_ellipses, plot_error_vs_time

    splits = SPLITS if split == "both" else ((split,) if isinstance(split, str) else tuple(split))
    for s in splits:
        if s not in SPLITS:
            raise DataError(f"unknown split {s!r}", field="split", fix="use grouped, random or both")
    names = tuple(models) if models is not None else MODEL_NAMES
    unknown = [n for n in names if n not in MODEL_NAMES]
    if unknown:
        raise DataError(f"unknown model {unknown[0]!r}", field="models", fix=f"choose from {', '.join(MODEL_NAMES)}")
    data = load_baseline_data(dataset_folder, flagged=flagged)
    dataset_path = Path(dataset_folder)
    out_dir = Path(out) if out is not None else (dataset_path if dataset_path.is_dir() else dataset_path.parent)
    out_dir.mkdir(parents=True, exist_ok=True)

    estimators = make_models(names, random_state=random_state, n_features=data.X.shape[1])
    jobs = [(s, n) for s in splits for n in names]
    results = []
    bar = tqdm(jobs, desc="baselines", unit="model", disable=not progress)
    for s, n in bar:
        bar.set_postfix_str(f"{n} ({s})")
        results.append(evaluate_model(n, estimators[n], data.X, data.y, data.groups, s, random_state, n_splits))
    bound = bound_rms_mm(data.physical_limit)
    table = results_table(results, bound)

    files = {
        "table (CSV)": out_dir / f"{TABLE_NAME}.csv",
        "table (parquet)": out_dir / f"{TABLE_NAME}.parquet",
        "error vs fit time": out_dir / "baselines_error_vs_time.png",
    }
    table.to_csv(files["table (CSV)"], index=False)
    table.to_parquet(files["table (parquet)"], index=False)
    plot_error_vs_time(results, files["error vs fit time"], bound)
    for s in splits:
        key = f"error ellipses ({s})"
        files[key] = out_dir / f"baselines_ellipses_{s}.png"
        plot_error_ellipses([r for r in results if r.split == s], files[key], data.layout)
    files["report"] = out_dir / "report.md"
    text = _markdown(data, table, bound, splits, files, random_state)
    files["report"].write_text(text, encoding="utf-8")
    if echo:
        print(format_table(table))
        if bound is not None:
            print(f"Cramér-Rao bound (RMS over positions): {bound:.3f} mm")
        print(f"wrote {files['report']}")
    return Report(tuple(results), table, bound, text, files)

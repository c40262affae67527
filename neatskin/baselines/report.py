"""The baseline report: every model over repeated splits, the physics inversion, the bound; table, report.md, PNGs.

`run_baselines(dataset, split, models, out)` is what the CLI and the campaign runner call.
Per model and split the table gives mean, std over repeats and the 95 % interval of the mean
of every figure (mean and median error, RMS, both MSEs, share within the probe radius, share
of failures). When the dataset folder holds `physical_limit.parquet` (Cramér-Rao bound per
position, from the dry run), any result whose RMS error is below the electronics-only bound
(`crb_mm`) is flagged as memorisation; the bound with the scene's nuisances (`crb_nuisance_mm`:
depth, drift, placement) is shown beside it, in the table, the text and a map (the table's rows, ratios, flag and
warnings are `resultstable`'s). Warnings (few test rows, folds cut, errors larger than the skin, memorisation)
are logged, raised as `BaselineWarning` and listed at the top of report.md.
"""

from __future__ import annotations

import functools
import logging
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.baselines.dataset import BaselineData, load_baseline_data
from neatskin.baselines.evaluate import (
    BaselineWarning,
    ModelResult,
    collect_results,
    fit_tasks,
    result_from_predictions,
)
from neatskin.baselines.floortext import Floors, bound_spread_mm, comparable, read_floors, skin_extent_mm
from neatskin.baselines.metrics import PROBE_RADIUS_MM
from neatskin.baselines.models import (
    DESCRIPTIONS,
    INVERSION_COST_S_PER_PRESS,
    INVERSION_MAX_PRESSES,
    MODEL_NAMES,
    PHYSICS_MODELS,
    SMALL_ROWS,
    TRAIN_ROW_CAP,
    fit_cost_s,
    make_models,
)
from neatskin.baselines.offskin import offskin_text, prediction_box_mm
from neatskin.baselines.reporttext import markdown_report
from neatskin.baselines.resultstable import BOUND_COLUMNS, bound_rms_mm, result_warnings, results_table
from neatskin.baselines.splits import SPLITS, repeat_splits
from neatskin.baselines.tasks import Task, run_tasks
from neatskin.errors import ConfigError, DataError

logger = logging.getLogger(__name__)

# Judd et al., section IV: the ten networks' average and the best network's (lowest MSE, Fig. 9), as reported
PAPER_REAL_SKIN = {
    "mean_error_mm": 2.03,
    "std_error_mm": 0.26,
    "mse_mm2": 3.32,
    "best_mean_error_mm": 1.82,
    "best_mse_mm2": 2.15,
    "best_within_probe": (54, 66),
}
TABLE_NAME = "baselines"
DEFAULT_REPEATS = 10
SPLIT_CHOICES = {"both": ("grouped", "random"), "all": SPLITS}  # "random" brings "design" when it fits
# The report's models when none are named: the ones that answer the paper's question (random split) and the
# new-position question (grouped split). On the paper dry run (10 repeats, docs/baselines.md "What the default
# report spends") kernel ridge is behind k-NN on the random and design splits and behind the extra trees on
# every split, and the MLP is level with the extra trees on the grouped split (within the spread over repeats)
# and behind them on the others, for 60 % of the report's CPU between them. ALL_MODELS ("all") is the full matrix.
DEFAULT_MODELS = ("ridge", "knn", "extra_trees", "lm_network", "inversion")
ALL_MODELS = "all"


@dataclass(frozen=True)
class Report:
    """What run_baselines produced: results, the table, the bound, warnings, the text and the files written."""

    results: tuple[ModelResult, ...]
    table: pd.DataFrame
    bound_rms_mm: float | None
    text: str
    files: dict[str, Path] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    time_s: float = 0.0
    bound_nuisance_rms_mm: float | None = None  # the same pooled bound with the scene's nuisances
    # both bounds' median over positions and where they exceed the probe radius (`bound_spread_mm`), or None
    spreads: tuple[tuple[float, int, int] | None, ...] = (None, None)
    # whether each bound is compared with the results (finite and within the skin everywhere: floortext.comparable)
    compared: tuple[bool, ...] = (True, True)
    floors: Floors | None = None


def _warn(notes: Iterable[str]) -> None:
    for note in notes:  # a warning reaches the terminal once (Python's warning display); the log keeps it too
        logger.info("warning: %s", note)
        warnings.warn(note, BaselineWarning, stacklevel=3)


def _resolve(split: str | Iterable[str], models: str | Iterable[str] | None, data: BaselineData):
    if isinstance(split, str):
        splits = SPLIT_CHOICES.get(split, (split,))
    else:
        splits = tuple(split)
    implied = "random" in splits and "design" not in splits
    if implied:  # the random split's Fig. 9 comes from the 11 x 6 design
        splits = (*splits, "design")
    for s in splits:
        if s not in SPLITS:
            raise DataError(f"unknown split {s!r}", field="split", fix="use grouped, random, design or both")
    known = MODEL_NAMES + PHYSICS_MODELS
    chosen = (models,) if isinstance(models, str) else tuple(models) if models is not None else None
    if chosen == (ALL_MODELS,):
        chosen, models = known, None  # the full matrix; the inversion's size guard applies as to the default
    names = chosen if chosen is not None else DEFAULT_MODELS
    unknown = [n for n in names if n not in known]
    if unknown:
        raise DataError(f"unknown model {unknown[0]!r}", field="models", fix=f"choose from {', '.join(known)}")
    learned = tuple(n for n in names if n in MODEL_NAMES)
    physics = tuple(n for n in names if n in PHYSICS_MODELS)
    notes = []
    if physics and data.layout is None:
        if models is not None:
            notes.append("inversion skipped: the dataset names no layout (manifest.json), so there is no forward model")
        physics = ()
    n_rows = len(data.y)
    if physics and models is None and n_rows > INVERSION_MAX_PRESSES:
        cpu_min = INVERSION_COST_S_PER_PRESS * n_rows / 60
        notes.append(
            f"inversion skipped: {n_rows:,} presses would take about {cpu_min:.0f} CPU minutes "
            f"(more than {INVERSION_MAX_PRESSES:,} presses); name it (--models ...,inversion) to run it anyway"
        )
        physics = ()
    return splits, learned, physics, notes, implied


def _inversion_model_text(inversion_model: str, data: BaselineData) -> str:
    """Refuses an unknown inversion model, or "fe-kernel" where no kernel of the dataset's layout and probe is
    packaged or cached (ConfigError, before any fit); what the report adds to the inversion's description."""
    from neatskin.skin.model import DEFORMATIONS

    if inversion_model not in DEFORMATIONS:
        raise ConfigError(
            f"inversion model {inversion_model!r} is unknown",
            field="--inversion-model",
            fix=f"pass one of {', '.join(DEFORMATIONS)}",
        )
    if inversion_model == "parametric":
        return ""
    from neatskin.skin.kernel import KernelSpec, load_kernel

    probe_mm = data.probe_radius_mm or PROBE_RADIUS_MM
    try:
        load_kernel(KernelSpec.for_layout(data.layout, probe_mm), compute=False)
    except FileNotFoundError as exc:
        raise ConfigError(
            f"--inversion-model fe-kernel: {exc}",
            field="--inversion-model",
            fix="run `neatskin skin mechanics` for this layout and a probe of radius "
            f"{probe_mm:g} mm first, or pass --inversion-model parametric",
        ) from exc
    return (
        "; its forward model the finite-element pinch kernel (--inversion-model fe-kernel), not the parametric pinch "
        "(docs/baselines.md compares the two)"
    )


def estimated_wall_s(tasks: list[Task], n_jobs: int) -> float:
    """The tasks' estimated seconds (models.fit_cost_s, rough) shared over the workers, never below the longest."""
    import os

    workers = (os.cpu_count() or 1) if n_jobs < 0 else max(1, n_jobs)
    costs = [t.cost_s for t in tasks] or [0.0]
    return max(sum(costs) / workers, max(costs))


def run_baselines(
    dataset_folder: str | Path,
    split: str | Iterable[str] = "grouped",
    models: str | Iterable[str] | None = None,
    out: str | Path | None = None,
    *,
    flagged: str = "saturate",
    random_state: int | None = 0,
    n_splits: int = 5,
    progress: bool = True,
    n_repeats: int = DEFAULT_REPEATS,
    n_jobs: int | None = None,
    backend: str | None = None,
    lm_restarts: int | None = 1,
    confirm: Callable[[float], None] | None = None,
    inversion_model: str = "parametric",
) -> Report:
    """Evaluate the baselines over repeated splits, print the table, and write report.md, CSV, parquet and PNGs.

    split: "grouped", "random", "design", "both" (all three) or a list; "random" brings "design" (its Fig. 9).
    models: names from MODEL_NAMES and "inversion" (inversion needs the dataset's layout); None: DEFAULT_MODELS;
        "all" (or ["all"]): every model.
    n_repeats: (seed, split) repeats per model and split, one fit each.
    n_jobs: processes for the fits, this one among them (default: every core, or 1 below SMALL_ROWS presses);
        backend: joblib's.
    lm_restarts: restarts per LM fit (default 1: each repeat trains one network, as each of the paper's ten).
    out: folder for the outputs (the dataset folder by default).
    confirm(estimate_s): told the estimated wall time before any fit (the CLI prints it and may refuse).
    inversion_model: the physics inversion's forward model (`skin_inversion`'s `deformation`): "parametric" (the
        default) or "fe-kernel" (the finite-element pinch kernel of the dataset's layout and probe, packaged or
        cached; a ConfigError before any fit when there is none).
    """
    from tqdm.auto import tqdm

    from neatskin.baselines.inversion import skin_inversion
    from neatskin.baselines.plots import floors_mm, plot_bound_map, plot_error_ellipses, plot_error_vs_time

    started = time.perf_counter()
    data = load_baseline_data(dataset_folder, flagged=flagged)
    splits, learned, physics, notes, design_implied = _resolve(split, models, data)
    inversion_text = _inversion_model_text(inversion_model, data) if physics else ""
    dataset_path = Path(dataset_folder)
    out_dir = Path(out) if out is not None else (dataset_path if dataset_path.is_dir() else dataset_path.parent)
    _check_writable(out_dir)  # before the fits: a report that cannot be written must not cost them first

    split_repeats = {}
    for s in splits:
        try:
            reps, split_notes = repeat_splits(s, data.groups, n_repeats, random_state, n_splits)
        except DataError as exc:
            if not (s == "design" and design_implied):
                raise
            notes.append(f"design split skipped: {exc.problems[0].message}")
            continue
        split_repeats[s] = reps
        notes += split_notes
    splits = tuple(split_repeats)
    n_rows = len(data.y)
    if n_jobs is None:
        n_jobs = 1 if n_rows < SMALL_ROWS else -1
    train_rows = int(np.mean([len(r.train) for reps in split_repeats.values() for r in reps]))
    estimators = make_models(
        learned, random_state=random_state, n_features=data.X.shape[1], n_rows=train_rows, lm_restarts=lm_restarts
    )
    caps = {n: TRAIN_ROW_CAP[n] for n in learned if train_rows > TRAIN_ROW_CAP.get(n, train_rows)}
    if caps:
        capped = ", ".join(f"{n} on {cap:,}" for n, cap in caps.items())
        notes.append(
            f"{train_rows:,} training rows per fit: {capped}, drawn evenly over the positions (keyed by the "
            "repeat's seed; models.TRAIN_ROW_CAP bounds their memory and time); the other models and every "
            "test row use all rows"
        )
    costs = {n: fit_cost_s(n, min(train_rows, caps.get(n, train_rows))) for n in learned}
    tasks = fit_tasks(estimators, data.X, data.y, data.groups, split_repeats, costs, caps)
    if physics:  # one task beside the fits: it needs no training, and runs while they do
        tasks.append(
            Task(
                ("inversion",),
                INVERSION_COST_S_PER_PRESS * n_rows,
                functools.partial(skin_inversion, deformation=inversion_model),
                (data.layout, data.X, data.skin_fidelity or "deformation", data.probe_radius_mm or PROBE_RADIUS_MM),
            )
        )
    if confirm is not None:
        confirm(estimated_wall_s(tasks, n_jobs))
    bar = tqdm(total=len(tasks), desc="baselines", unit="task", disable=not progress)

    def advance(done: int, total: int) -> None:
        bar.update(done - bar.n)

    # this process is one of the fits' lanes (tasks.run_tasks), so the figures, the bound map too, are drawn
    # after the fits: matplotlib is imported once the workers have ended, not beside them
    outputs = run_tasks(tasks, n_jobs=n_jobs, backend=backend, progress=advance)
    bar.close()
    box = prediction_box_mm(data.layout, data.y)  # every model's predictions are clipped to the skin (offskin)
    learned_results = collect_results(learned, split_repeats, outputs, data.y, data.groups, box)
    results = []
    physics_results = []
    if physics:
        inv = outputs[("inversion",)]
        per_row_s = inv.time_s / max(n_rows, 1)
        for s in splits:
            physics_results.append(
                result_from_predictions(
                    "inversion", s, split_repeats[s], inv.xy_mm, data.y, data.groups, per_row_s, box
                )
            )
    for s in splits:
        results += [r for r in learned_results if r.split == s] + [r for r in physics_results if r.split == s]
    bound = bound_rms_mm(data.physical_limit)
    nuisance_bound = bound_rms_mm(data.physical_limit, "crb_nuisance_mm")
    radius = data.probe_radius_mm or PROBE_RADIUS_MM
    extent = skin_extent_mm(data.layout, data.y)
    spreads = {c: bound_spread_mm(data.physical_limit, c, radius) for c in BOUND_COLUMNS}
    compared = {c: comparable(data.physical_limit, c, extent) for c in BOUND_COLUMNS}
    floors = read_floors(data.physical_limit, radius)
    table = results_table(results, bound, nuisance_bound, floors, compared)
    notes += result_warnings(table, data, bound)
    _warn(notes)

    files: dict[str, Path] = {
        "table (CSV)": out_dir / f"{TABLE_NAME}.csv",
        "table (parquet)": out_dir / f"{TABLE_NAME}.parquet",
        "error vs time": out_dir / "baselines_error_vs_time.png",
    }
    table.to_csv(files["table (CSV)"], index=False)
    table.to_parquet(files["table (parquet)"], index=False)
    plot_error_vs_time(results, files["error vs time"], bound, table, floors=floors_mm(data.physical_limit, extent))
    if data.physical_limit is not None and len(data.physical_limit):
        files["bound map"] = plot_bound_map(data.physical_limit, out_dir / "baselines_bound_map.png", data.layout)
    for s in splits:
        if s == "random":  # one prediction per test position: Fig. 9 is drawn from the 11 x 6 design instead
            continue
        key = f"error ellipses ({s})"
        files[key] = out_dir / f"baselines_ellipses_{s}.png"
        plot_error_ellipses([r for r in results if r.split == s], files[key], data.layout)
    files["report"] = out_dir / "report.md"
    elapsed = time.perf_counter() - started
    text = markdown_report(
        data=data,
        table=table,
        bound=bound,
        nuisance_bound=nuisance_bound,
        spreads=spreads,
        compared=compared,
        extent_mm=extent,
        floors=floors,
        splits=splits,
        files=files,
        random_state=random_state,
        notes=notes,
        n_jobs=n_jobs,
        elapsed_s=elapsed,
        descriptions={n: DESCRIPTIONS[n] + (inversion_text if n == "inversion" else "") for n in (*learned, *physics)},
        paper=PAPER_REAL_SKIN,
        lm_restarts=lm_restarts,
        offskin=offskin_text(table, results, box, split_repeats, data),
    )
    files["report"].write_text(text, encoding="utf-8")
    return Report(
        tuple(results),
        table,
        bound,
        text,
        files,
        tuple(notes),
        elapsed,
        nuisance_bound,
        tuple(spreads.values()),
        tuple(compared.get(c, True) for c in spreads),
        floors,
    )


def _check_writable(folder: Path) -> None:
    """Create `folder` and write (then remove) a probe file in it, or one DataError naming it: a read-only dataset
    folder used to cost every fit of the report before the first file failed (the hostile-input audit)."""
    from neatskin.datasets.durable import probe_write

    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe_write(folder)
    except OSError as exc:
        raise DataError(
            f"cannot write the report there: {exc.strerror or exc}",
            file=str(folder),
            field="--out",
            fix="give a folder you can write with -o/--out (the dataset itself is only read)",
        ) from exc

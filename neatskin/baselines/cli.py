"""The `neatskin baselines` command: evaluate the regression baselines on a dataset and write the report."""

from __future__ import annotations

import argparse

from neatskin.cligroups import add_out, add_quiet, positive_finite


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "baselines",
        help="fit the paper's LM network and scikit-learn baselines on a dataset; write report.md, table, plots",
        description="Predict press positions from the pair resistance changes with every baseline model; print "
        "error against fit and predict time, and write report.md, baselines.csv/.parquet and PNG plots.",
    )
    parser.add_argument("dataset", help="campaign folder, merged dataset folder, or a presses .parquet file")
    parser.add_argument(
        "--split",
        choices=("grouped", "random", "design", "both", "all"),
        default="grouped",
        help="grouped: k-fold over positions (honest, default); random: the paper's 95/3/2 by row (brings the "
        "11 x 6 design for its Fig. 9 when the data allows); design: 11 positions x 6 presses held out; "
        "both: grouped and random; all: the three",
    )
    parser.add_argument(
        "--models",
        default=None,
        help="comma-separated, e.g. ridge,knn: any of ridge, knn, kernel_ridge, extra_trees, mlp, lm_network, "
        "inversion, or all (default: ridge, knn, extra_trees, lm_network, inversion; inversion, the physics "
        "baseline, needs the layout the manifest names)",
    )
    add_out(parser, "output folder (default: the dataset folder); a folder that already holds a report is refused")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing report in the output folder (its report files and plots are removed first)",
    )
    parser.add_argument(
        "--flagged",
        choices=("saturate", "drop", "keep", "refuse"),
        default="saturate",
        help="what to do with presses that carry flags (default: keep a cut pair's press with its dR saturated, "
        "drop every other flagged press; docs/baselines.md)",
    )
    parser.add_argument("--folds", type=int, default=5, help="folds over positions for the grouped split")
    parser.add_argument("--seed", type=int, default=0, help="seed for splits and model initialisation")
    parser.add_argument(
        "--repeats", type=int, default=10, help="(seed, split) repeats per model and split, one fit each (default 10)"
    )
    parser.add_argument(
        "--jobs", type=int, default=None, help="processes for the fits (default: every core; 1 on small datasets)"
    )
    parser.add_argument(
        "--lm-restarts", type=int, default=1, help="LM restarts per fit, best on validation (default 1 per repeat)"
    )
    parser.add_argument(
        "--inversion-model",
        choices=("parametric", "fe-kernel"),
        default="parametric",
        help="the physics inversion's forward model: the parametric pinch (default) or the finite-element pinch "
        "kernel of the dataset's layout and probe (packaged, or made by `neatskin skin mechanics`)",
    )
    add_quiet(parser)
    parser.add_argument("--yes", action="store_true", help="run even when the estimate is above --max-hours")
    parser.add_argument(
        "--max-hours",
        type=positive_finite,
        default=1.0,
        help="refuse a run estimated longer than this without --yes (default 1)",
    )
    parser.set_defaults(handler=handler)


REPORT_FILES = ("report.md", "baselines.csv", "baselines.parquet", "baselines_*.png")


def _check_output(args: argparse.Namespace) -> None:
    """A new report never lies beside files of an older one: refuse, or with --overwrite remove them first."""
    from pathlib import Path

    from neatskin.errors import ConfigError

    if args.folds < 2:
        raise ConfigError(
            f"--folds {args.folds}: a k-fold split needs at least 2 folds",
            field="--folds",
            fix="pass --folds 2 or more (default 5)",
        )
    dataset = Path(args.dataset)
    out = Path(args.out) if args.out is not None else (dataset if dataset.is_dir() else dataset.parent)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out} is a file, not a folder", field="--out", fix="give --out a folder")
    old = sorted(p for pattern in REPORT_FILES for p in out.glob(pattern)) if out.is_dir() else []
    if old and not args.overwrite:
        raise ConfigError(
            f"{out} already holds a baseline report ({', '.join(p.name for p in old[:3])}"
            f"{', ...' if len(old) > 3 else ''})",
            field="--out",
            fix="write to a new folder with --out NEW_FOLDER, or replace it with --overwrite",
        )
    for path in old:
        path.unlink()


def handler(args: argparse.Namespace) -> int:
    from neatskin.baselines.report import run_baselines
    from neatskin.baselines.summary import report_summary
    from neatskin.errors import confirm_cost

    _check_output(args)
    models = [m.strip() for m in args.models.split(",") if m.strip()] if args.models else None
    report = run_baselines(
        args.dataset,
        split=args.split,
        models=models,
        out=args.out,
        flagged=args.flagged,
        random_state=args.seed,
        n_splits=args.folds,
        progress=not args.quiet,
        n_repeats=args.repeats,
        n_jobs=args.jobs,
        lm_restarts=args.lm_restarts,
        inversion_model=args.inversion_model,
        confirm=lambda estimate_s: confirm_cost(
            estimate_s,
            args.max_hours * 3600.0,
            args.yes,
            what=f"baselines on {args.dataset}",
            basis="models.fit_cost_s per fit, rough; the workers' cores assumed free",
        ),
    )
    print(report_summary(report))
    return 0

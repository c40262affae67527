"""The `neatskin design` command group: `neatskin design study STUDY.toml` sweeps candidate skin layouts and
electrode placements and writes candidates.parquet, per-candidate maps and report.md."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    design = subparsers.add_parser(
        "design",
        help="design a skin before fabricating it: predicted error of candidate layouts",
        description="Design studies: the predicted localisation error of candidate layouts and electrode placements.",
    )
    commands = design.add_subparsers(dest="design_command", metavar="DESIGN_COMMAND", required=True)
    study = commands.add_parser(
        "study",
        help="run a design study (resumes: candidates already in --out are skipped)",
        description="Evaluate every candidate of a study TOML (see protocols/studies/grid5.toml) and write "
        "candidates.parquet, maps/ and report.md with the Pareto front. A killed run resumes where it stopped.",
    )
    study.add_argument("study", help="study TOML (protocols/studies/... resolves to the packaged copy)")
    study.add_argument("--out", default=None, help="output folder (default out/design/<study name>)")
    study.add_argument("--jobs", type=int, default=1, help="local worker processes (joblib; default 1)")
    study.add_argument("--scheduler", choices=("local", "dask"), default="local", help="where candidates run")
    study.add_argument(
        "--address", default=None, help="Dask scheduler address, tcp://HOST:PORT (with --scheduler dask)"
    )
    study.add_argument("--no-progress", action="store_true", help="no progress bar")
    study.add_argument("--no-png", action="store_true", help="skip the per-candidate map PNGs (parquet maps only)")
    study.set_defaults(handler=study_handler)
    validate = commands.add_parser(
        "validate",
        help="the study's predictions against simulated campaigns that are not the study's; can fail",
        description="Compare the study's learned errors, its physics (a study-trained model on campaign presses) and "
        "its ranking of candidates with simulated campaigns (other positions, folds, seeds, model; the protocol's "
        "scene for the ranking). Exit 0 when they agree, 1 when not. --negative-control scales the campaigns' pinch "
        "by 0.6 and must disagree. Writes the section into OUT/report.md.",
    )
    validate.add_argument("study", help="study TOML")
    validate.add_argument("--out", default=None, help="output folder (default out/design/<study name>)")
    validate.add_argument("--protocol", default="protocols/paper.toml", help="protocol whose scene the campaigns use")
    validate.add_argument(
        "--negative-control", action="store_true", help="campaigns with the pinch x 0.6: must disagree"
    )
    validate.add_argument("--no-power", action="store_true", help="skip the power sweep of pinch changes")
    validate.add_argument("--jobs", type=int, default=2, help="joblib processes (default 2)")
    validate.set_defaults(handler=validate_handler)


def study_handler(args: argparse.Namespace) -> int:
    from pathlib import Path

    from neatskin.design.runner import run_study
    from neatskin.design.study import load_study

    study = load_study(args.study)
    out = Path(args.out) if args.out else Path("out") / "design" / study.name
    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if args.no_progress:
            return
        if bar is None:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=done, unit="candidate", desc=f"study {study.name}")
            return
        bar.update(done - bar.n)

    try:
        frame = run_study(
            study,
            out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            address=args.address,
            progress=progress,
            pngs=not args.no_png,
        )
    finally:
        if bar is not None:
            bar.close()
    best = frame.sort_values("bound_mean_capped_mm").iloc[0]
    print(f"{len(frame)} candidates -> {out / 'candidates.parquet'}, report {out / 'report.md'}")
    print(
        f"lowest capped mean bound: {best['placement']} {best['electrodes']} electrodes on "
        f"{best['nx']} x {best['ny']}: {best['bound_mean_capped_mm']:.3g} mm"
    )
    return 0


def validate_handler(args: argparse.Namespace) -> int:
    from pathlib import Path

    from neatskin.design.study import load_study
    from neatskin.design.validate import NEGATIVE_PINCH, validate_study, write_section
    from neatskin.design.validatetext import markdown, table_lines, verdict_lines

    study = load_study(args.study)
    out = Path(args.out) if args.out else Path("out") / "design" / study.name
    scale = NEGATIVE_PINCH if args.negative_control else 1.0
    v = validate_study(study, args.protocol, pinch_scale=scale, power=not args.no_power, n_jobs=args.jobs)
    print("\n".join([*table_lines(v), *verdict_lines(v)]))
    write_section(out / "report.md", markdown(v, study.name, str(args.protocol)))
    print(f"section written to {out / 'report.md'}")
    return 0 if v.agree else 1

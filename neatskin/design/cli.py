"""The `neatskin design` command group: `neatskin design study STUDY.toml` sweeps candidate skin layouts and
electrode placements and writes candidates.parquet, per-candidate maps and report.md."""

from __future__ import annotations

import argparse
from typing import Any

from neatskin.cligroups import add_out, add_quiet, positive_finite


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
    add_out(study, "output folder (default out/design/<study name>)")
    study.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="local worker processes (joblib; default: the cores this process may use)",
    )
    study.add_argument("--yes", action="store_true", help="run even when the estimate is above --max-hours")
    study.add_argument(
        "--max-hours",
        type=positive_finite,
        default=1.0,
        help="refuse a study estimated longer than this without --yes (default 1)",
    )
    study.add_argument("--scheduler", choices=("local", "dask"), default="local", help="where candidates run")
    study.add_argument(
        "--address", default=None, help="Dask scheduler address, tcp://HOST:PORT (with --scheduler dask)"
    )
    add_quiet(study)
    study.add_argument("--no-png", action="store_true", help="skip the per-candidate map PNGs (parquet maps only)")
    study.set_defaults(handler=study_handler)
    validate = commands.add_parser(
        "validate",
        help="the study's predictions against simulated campaigns that are not the study's; can fail",
        description="Compare the study's learned errors, its physics (a study-trained model on campaign presses) and "
        "its ranking of candidates with simulated campaigns (other positions, folds, seeds, model; the protocol's "
        "scene for the ranking). Exit 0 when they agree, 1 when not. --negative-control scales the campaigns' pinch "
        "by 0.6 and must disagree. The study's optimised placements are checked too when `design study` has made them "
        "in OUT for this same study file (else a line says they are left out). Writes the section into OUT/report.md.",
    )
    validate.add_argument("study", help="study TOML")
    add_out(validate, "output folder (default out/design/<study name>)")
    validate.add_argument("--protocol", default="protocols/paper.toml", help="protocol whose scene the campaigns use")
    validate.add_argument(
        "--negative-control", action="store_true", help="campaigns with the pinch x 0.6: must disagree"
    )
    validate.add_argument("--no-power", action="store_true", help="skip the power sweep of pinch changes")
    validate.add_argument("--jobs", type=int, default=2, help="joblib processes (default 2)")
    add_quiet(validate)
    validate.set_defaults(handler=validate_handler)


def study_handler(args: argparse.Namespace) -> int:

    from neatskin.design.runner import run_study
    from neatskin.design.study import load_study, study_out_dir

    study = load_study(args.study)
    out = study_out_dir(study, args.out)
    _confirm_cost(study, out, args)
    # a Dask run reports whole candidates; a local run's ticks move the bar within each (per tile of presses,
    # learned seed, inversion step)
    dask = args.scheduler == "dask"
    bar = _Bar(args.quiet, follow=dask, unit="candidate", desc=f"study {study.name}", bar_format=_BAR)
    try:
        frame = run_study(
            study,
            out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            address=args.address,
            progress=bar.progress,
            tick=None if dask else bar.tick,
            pngs=not args.no_png,
        )
    finally:
        bar.close()
    best = frame.sort_values("bound_mean_capped_mm").iloc[0]
    print(f"{len(frame)} candidates -> {out / 'candidates.parquet'}, report {out / 'report.md'}")
    print(
        f"lowest capped mean bound: {best['placement']} {best['electrodes']} electrodes on "
        f"{best['nx']} x {best['ny']}: {best['bound_mean_capped_mm']:.3g} mm"
    )
    return 0


_BAR = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total_fmt} candidates [{elapsed}<{remaining}]"


class _Bar:
    """A tqdm bar on stderr, made at the first progress call (when the total is known), none with --quiet.
    follow: later progress calls move it to `done` (else only `tick` moves it, in shares of a unit)."""

    def __init__(self, quiet: bool, follow: bool = True, **tqdm_kwargs) -> None:
        self.quiet, self.follow, self.kwargs = quiet, follow, tqdm_kwargs
        self.bar: Any = None  # a tqdm, once the total is known

    def progress(self, done: int, total: int) -> None:
        if self.quiet:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, **self.kwargs)
        elif self.follow:
            self.bar.update(done - self.bar.n)

    def tick(self, share: float) -> None:
        if self.bar is not None:
            self.bar.update(share)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _confirm_cost(study, out, args: argparse.Namespace) -> None:
    """Print the study's estimated time before any work; refuse beyond --max-hours unless --yes."""
    from neatskin.design.candidates import expand
    from neatskin.design.cost import BASIS, machine_load, study_seconds
    from neatskin.design.runner import default_jobs, done_ids
    from neatskin.errors import confirm_cost

    jobs = args.jobs or default_jobs()
    finished = done_ids(out)
    todo = [c for c in expand(study) if c.candidate_id not in finished]
    dask = args.scheduler == "dask"
    workers = 1 if dask else min(jobs, max(1, len(todo)))
    load, cores = (0.0, 1) if dask else machine_load()  # a cluster's size and load are not known here
    estimate_s = study_seconds(study, todo, workers, load, cores)
    where = "one free worker of the Dask cluster (divide by its workers)" if dask else f"{workers} worker(s)"
    confirm_cost(
        estimate_s,
        args.max_hours * 3600.0,
        args.yes,
        what=f"design study {study.name}: {len(todo)} candidate(s) on {where}",
        basis=BASIS if dask else f"{BASIS} ({load:.1f} on {cores} cores)",
        flag="--yes",
        load_scaled=True,
    )


def validate_handler(args: argparse.Namespace) -> int:
    from neatskin.design.study import load_study, study_out_dir
    from neatskin.design.validate import NEGATIVE_PINCH, validate_study, write_section
    from neatskin.design.validatetext import markdown, table_lines, verdict_lines

    study = load_study(args.study)
    out = study_out_dir(study, args.out)
    scale = NEGATIVE_PINCH if args.negative_control else 1.0
    bar = _Bar(args.quiet, unit="check", desc=f"validate {study.name}")
    try:
        v = validate_study(
            study,
            args.protocol,
            pinch_scale=scale,
            power=not args.no_power,
            n_jobs=args.jobs,
            progress=bar.progress,
            out=out,
        )
    finally:
        bar.close()
    print("\n".join([*table_lines(v), *verdict_lines(v)]))
    write_section(out / "report.md", markdown(v, study.name, str(args.protocol)))
    print(f"section written to {out / 'report.md'}")
    return 0 if v.agree else 1

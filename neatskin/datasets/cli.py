"""`neatskin dataset info|validate|merge|split|export|plot`: a thin layer over neatskin.datasets.curate, .validate,
.plots and .pressplots. Heavy imports happen inside the handlers.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from neatskin.cligroups import add_out
from neatskin.errors import CheckFailed


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "dataset",
        help="describe (info), validate, merge, split, export and plot campaign datasets",
        description="Curate campaign datasets: describe (info), validate, merge, split by position, export and plot "
        "them. Each action reads a campaign folder (written by `neatskin campaign run`) or its presses.parquet "
        "(docs/datasets.md).",
    )
    sub = parser.add_subparsers(dest="dataset_command", metavar="ACTION", required=True)

    info = sub.add_parser("info", aliases=["describe"], help="summarise a campaign folder or press parquet file")
    info.add_argument("path", type=Path, help="campaign folder or .parquet file")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.set_defaults(handler=_info)

    val = sub.add_parser(
        "validate",
        help="check schema, NaNs, duplicates, bounds, flags and the manifest; exit status 1 when anything is wrong (docs/cli.md)",
    )
    val.add_argument("path", type=Path, help="campaign folder or .parquet file")
    val.add_argument("--layout", type=Path, help="skin layout TOML (default: the one the manifest names)")
    val.add_argument("--allow-flagged", action="store_true", help="do not count flagged presses as problems")
    val.set_defaults(handler=_validate)

    mer = sub.add_parser("merge", help="merge campaigns into one dataset (press and position ids re-keyed)")
    mer.add_argument("folders", type=Path, nargs="+", help="campaign folders or press .parquet files (two or more)")
    add_out(mer, "new folder to write", required=True)
    mer.add_argument("--allow-mixed", action="store_true", help="merge campaigns on different layouts or wirings")
    mer.add_argument(
        "--allow-incomplete",
        action="store_true",
        help="merge campaigns that are interrupted, crashed or still running (recorded in the merged manifest)",
    )
    mer.add_argument(
        "--allow-invalid",
        action="store_true",
        help="merge campaigns `dataset validate` refuses (their problems recorded in the merged manifest)",
    )
    mer.add_argument(
        "--allow-mixed-rigs",
        action="store_true",
        help="merge campaigns of different rigs (a dry run with a real-printer run, a simulated DAQ with a real "
        "one); each source's rig is recorded in the merged manifest and named on its card",
    )
    mer.set_defaults(handler=_merge)

    spl = sub.add_parser("split", help="split into train/ and test/ by position (repeats never straddle)")
    spl.add_argument("path", type=Path, help="campaign folder or .parquet file")
    add_out(spl, "new folder for train/ and test/", required=True)
    spl.add_argument("--test-fraction", type=float, default=0.2, help="share of positions in test (default 0.2)")
    spl.add_argument("--seed", type=int, default=0, help="seed of the position shuffle (default 0)")
    spl.set_defaults(handler=_split)

    exp = sub.add_parser(
        "export",
        help="export the presses as one parquet or CSV file, or as a Hugging Face dataset folder (--format hf); "
        "host names and local paths are removed",
    )
    exp.add_argument("path", type=Path, help="campaign folder or .parquet file")
    add_out(exp, "file (parquet, csv) or folder (hf) to write", required=True)
    exp.add_argument(
        "--format", choices=("parquet", "csv", "hf"), help="default: from the output's suffix; hf: a dataset folder"
    )
    exp.add_argument("--drop-flagged", action="store_true", help="leave out presses that carry flags")
    exp.add_argument("--license", default=None, help="hf: the dataset card's licence (default cc-by-4.0)")
    exp.add_argument(
        "--test-fraction", type=float, default=0.2, help="hf: share of positions in the test split (default 0.2)"
    )
    exp.add_argument("--seed", type=int, default=0, help="hf: seed of the position split (default 0)")
    exp.set_defaults(handler=_export)

    plot = sub.add_parser(
        "plot",
        help="draw the sensitivity map (paper Fig. 8) and the press map as PNG; with --press one press, with --drift "
        "the baseline drift",
    )
    plot.add_argument("path", type=Path, help="campaign folder or .parquet file")
    add_out(plot, "folder for the PNG files", required=True)
    plot.add_argument(
        "--kind", choices=("sensitivity", "presses", "all"), default="all", help="which maps to draw (default all)"
    )
    plot.add_argument(
        "--layout",
        type=Path,
        help="skin layout TOML (default: the one the manifest names; for a lone .parquet, the one its metadata names)",
    )
    plot.add_argument("--press", type=int, metavar="ID", help="also one press: R per pair and FSR against time")
    plot.add_argument(
        "--drift",
        action="store_true",
        help="also every pair's baseline R against press order (a press that cut a pair off: a gap in its line)",
    )
    plot.set_defaults(handler=_plot)


def _writes_outputs(handler):
    """A command that writes a new dataset (merge, split, export, plot): a write that fails is fixed by running the
    command again, not by `resume` (the campaign writer's next step, which the shared write errors name)."""
    import functools

    from neatskin.errors import DataError

    @functools.wraps(handler)
    def run(args: argparse.Namespace) -> int:
        try:
            return handler(args)
        except DataError as exc:
            from neatskin.datasets.durable import then_instead_of_resume

            raise then_instead_of_resume(exc, "then run the command again") from exc

    return run


def _info(args: argparse.Namespace) -> int:
    from neatskin.datasets.curate import describe, format_description
    from neatskin.datasets.validate import validate_dataset

    info = describe(args.path)
    problems = validate_dataset(args.path)  # as `dataset validate` with its defaults: the two always agree
    info["validation"] = (
        "valid"
        if not problems
        else (
            f"{len(problems)} problem(s), e.g. {problems[0].message} (details: neatskin dataset validate {args.path})"
        )
    )
    print(json.dumps(info, indent=2, default=str) if args.json else format_description(info))
    return 0


def _validate(args: argparse.Namespace) -> int:
    from neatskin.datasets.validate import validate_dataset
    from neatskin.layout import load_layout

    layout = load_layout(args.layout) if args.layout else None
    notes: list[str] = []
    problems = validate_dataset(args.path, layout=layout, allow_flagged=args.allow_flagged, notes=notes)
    for note in notes:
        print(f"{args.path}: note: {note}", file=sys.stderr)
    if problems:  # the check's verdict: printed, one line per problem, by neatskin.cli with exit status 1
        raise CheckFailed(problems=problems)
    print(f"{args.path}: valid")
    return 0


@_writes_outputs
def _merge(args: argparse.Namespace) -> int:
    from neatskin.datasets.curate import merge
    from neatskin.datasets.reader import read_metadata

    out = merge(
        args.folders,
        args.out,
        allow_mixed=args.allow_mixed,
        allow_incomplete=args.allow_incomplete,
        allow_invalid=args.allow_invalid,
        allow_mixed_rigs=args.allow_mixed_rigs,
    )
    from neatskin.datasets.curation import manifest_or_empty

    sources = read_metadata(out)["merged_from"]
    rigs: dict[str, list[str]] = {}  # each source folder's rig(s) in words, as the merged manifest records them
    for entry in manifest_or_empty(out).get("source_rigs") or []:
        rigs.setdefault(str(entry.get("source", entry.get("folder"))), []).append(str(entry.get("description")))
    for source in sources:
        ids = sorted(set(source["position_ids"].values()))
        span = f"{ids[0]}..{ids[-1]}" if ids else "none"
        rig = " + ".join(dict.fromkeys(rigs.get(source["folder"], []))) or "rig not recorded"
        print(
            f"{source['folder']} ({source['status']}; {rig}): {source['presses']} presses, press ids "
            f"+{source['press_id_offset']}, {len(ids)} physical positions (merged ids {span})"
        )
    print(f"wrote {out}")
    return 0


@_writes_outputs
def _split(args: argparse.Namespace) -> int:
    from neatskin.datasets.curate import split
    from neatskin.datasets.reader import read_presses

    for name, folder in split(args.path, args.out, args.test_fraction, args.seed).items():
        df = read_presses(folder)
        print(f"{name}: {folder} ({len(df)} presses, {df['position_id'].nunique()} positions)")
    return 0


@_writes_outputs
def _export(args: argparse.Namespace) -> int:
    from neatskin.datasets.curate import export, export_format

    if args.format == "hf":
        from neatskin.datasets.hfexport import DEFAULT_LICENSE, export_hf

        licence = args.license or DEFAULT_LICENSE
        out = export_hf(
            args.path,
            args.out,
            license=licence,
            test_fraction=args.test_fraction,
            seed=args.seed,
            drop_flagged=args.drop_flagged,
        )
        note = "" if args.license else " (the default: --license to change it)"
        print(f"wrote {out}: README.md (licence {licence}{note}), data/train and data/test by position")
        return 0
    fmt = export_format(args.out, args.format)
    print(f"wrote {export(args.path, args.out, fmt, drop_flagged=args.drop_flagged)}")
    return 0


@_writes_outputs
def _plot(args: argparse.Namespace) -> int:
    from neatskin.datasets.plots import plot_press_map, plot_sensitivity_map

    if args.kind in ("sensitivity", "all"):
        print(f"wrote {plot_sensitivity_map(args.path, args.out / 'sensitivity_map.png', args.layout)}")
    if args.kind in ("presses", "all"):
        print(f"wrote {plot_press_map(args.path, args.out / 'press_map.png', args.layout)}")
    if args.press is not None or args.drift:
        from neatskin.datasets.pressplots import plot_drift, plot_press

        if args.press is not None:
            print(f"wrote {plot_press(args.path, args.press, args.out / f'press-{args.press}.png')}")
        if args.drift:
            print(f"wrote {plot_drift(args.path, args.out / 'drift.png')}")
    return 0

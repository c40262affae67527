"""Benchmark of the dataset writer: a paper-sized campaign (100 positions x 28 repeats = 2,800 presses) written
press by press with durable parts, then finalized; side by side with fsync off and with raw waveforms.

    .venv/bin/python benchmarks/bench_datasets.py [--presses 2800] [--waveform-samples 5600] [--folder DIR]

Prints presses/s, time per durable press, finalize time, read-back and validate times. Target: the
writer's share of the dry-run paper campaign (60 s for everything) stays at a few ms per press.

Memory as campaigns grow: the writer alone (no fsync, as a dry run writes) at several sizes, each in a
fresh process, peak RSS after the presses and after finalize; optionally side by side with another
checkout of the toolkit in the same run:

    .venv/bin/python benchmarks/bench_datasets.py --memory 2800,28000 --compare /path/to/other/checkout

A 280,000-press merged dataset (issue 13): 100 relabelled copies of one finished campaign (e.g. a paper dry
run), merged, validated and reported on, each command in a fresh process (wall, CPU, peak RSS); --folder
keeps the copies for the next run:

    .venv/bin/python benchmarks/bench_datasets.py --merged 100 --source runs/paper --folder /tmp/m100 \
        --compare /path/to/other/checkout --baselines-args "--models ridge --repeats 1"
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from neatskin.datasets.manifest import create_manifest
from neatskin.datasets.reader import read_presses
from neatskin.datasets.validate import validate_dataset
from neatskin.datasets.writer import CampaignWriter
from neatskin.layout import load_layout
from neatskin.skin.synthetic import synthetic_rows

REPO = Path(__file__).resolve().parent.parent


def run_case(root: Path, name: str, layout, rows, *, fsync: bool, waveform_samples: int) -> dict:
    folder = root / name
    create_manifest(
        folder,
        seed=0,
        layout={"path": str(REPO / "protocols" / "skins" / "paper.toml")},
        counts={"planned": len(rows), "completed": len(rows)},
        status="complete",
        fsync=fsync,
    )
    rng = np.random.default_rng(0)
    waveforms = None
    if waveform_samples:
        waveforms = {
            "voltage_v": rng.normal(size=waveform_samples),
            "current_a": rng.normal(size=waveform_samples),
            "fsr_v": rng.normal(size=waveform_samples),
        }
    t0 = time.perf_counter()
    with CampaignWriter(folder, layout.pairs, {"seed": 0}, fsync=fsync) as writer:
        for row in rows:
            writer.write_press(row, waveforms)
        t1 = time.perf_counter()
        parts_read_s = _timed(lambda: read_presses(folder))
        finalize_s = _timed(writer.finalize)
    read_s = _timed(lambda: read_presses(folder))
    validate_s = _timed(lambda: validate_dataset(folder))
    size_mb = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
    return {
        "case": name,
        "presses": len(rows),
        "write_s": t1 - t0,
        "ms_per_press": 1e3 * (t1 - t0) / len(rows),
        "presses_per_s": len(rows) / (t1 - t0),
        "finalize_s": finalize_s,
        "read_parts_s": parts_read_s,
        "read_final_s": read_s,
        "validate_s": validate_s,
        "size_mb": size_mb,
    }


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


_MEMORY_CHILD = """
import json, resource, sys, tempfile, time, shutil
from pathlib import Path
from neatskin.datasets.writer import CampaignWriter
from neatskin.layout import load_layout
from neatskin.skin.synthetic import synthetic_rows
layout = load_layout(sys.argv[1])
n = int(sys.argv[2])
template = synthetic_rows(layout, 1, 1, seed=0, campaign="c")[0]
folder = Path(tempfile.mkdtemp(prefix="bench-memory-"))
rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
try:
    start = rss()
    t0 = time.perf_counter()
    writer = CampaignWriter(folder, layout.pairs, {"seed": 0, "campaign": "c"}, fsync=False)
    for press_id in range(n):
        writer.write_press({**template, "press_id": press_id})
    written, t1 = rss(), time.perf_counter()
    writer.finalize()
    t2 = time.perf_counter()
    print(json.dumps({"presses": n, "start_mb": start, "after_presses_mb": written, "after_finalize_mb": rss(),
                      "write_s": t1 - t0, "finalize_s": t2 - t1}))
finally:
    shutil.rmtree(folder, ignore_errors=True)
"""


def memory(sizes: list[int], checkouts: dict[str, Path]) -> None:
    """Peak RSS of the writer alone per campaign size and checkout, each in a fresh process."""
    layout = REPO / "protocols" / "skins" / "paper.toml"
    print(
        f"{'checkout':<10}{'presses':>9}{'start MB':>10}{'presses MB':>12}{'finalize MB':>13}{'write s':>9}{'final s':>9}"
    )
    for size in sizes:
        for label, checkout in checkouts.items():
            done = subprocess.run(
                [sys.executable, "-c", _MEMORY_CHILD, str(layout), str(size)],
                env={**os.environ, "PYTHONPATH": str(checkout)},
                cwd=checkout,  # `python -c` puts the working directory first on sys.path, before PYTHONPATH
                capture_output=True,
                text=True,
                check=True,
            )
            r = json.loads(done.stdout.strip().splitlines()[-1])
            print(
                f"{label:<10}{r['presses']:>9}{r['start_mb']:>10.0f}{r['after_presses_mb']:>12.0f}"
                f"{r['after_finalize_mb']:>13.0f}{r['write_s']:>9.1f}{r['finalize_s']:>9.1f}",
                flush=True,
            )


# ---- a 100-campaign merged dataset ---------------------------------------------------------------


def copy_campaign(source: Path, target: Path, index: int) -> Path:
    """A copy of a finished campaign folder relabelled as campaign `<name>-<index>` with seed `<seed> + index`:
    the campaign column, the parquet metadata, presses.copy.parquet, the manifest (campaign, seed, the protocol
    as run) and the sha256 it records for presses.parquet are rewritten together, so `dataset validate` accepts
    the copy as a complete campaign. The measured rows are the source's (only the labels differ); the wire log
    is not copied."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from neatskin.datasets.manifest import read_manifest, write_manifest
    from neatskin.datasets.schema import decode_metadata, encode_metadata
    from neatskin.datasets.writer import file_sha256, write_table_durably

    manifest = read_manifest(source)
    name, seed = f"{manifest['campaign']}-{index:03d}", int(manifest["seed"]) + index
    target.mkdir(parents=True)
    shutil.copytree(source / "inputs", target / "inputs")
    for extra in ("physical_limit.parquet",):
        if (source / extra).is_file():
            shutil.copyfile(source / extra, target / extra)
    table = pq.read_table(source / "presses.parquet")
    meta = {**decode_metadata(table.schema.metadata), "campaign": name, "seed": seed}
    column = table.schema.get_field_index("campaign")
    table = table.set_column(column, table.schema.field(column), pa.array([name] * table.num_rows, pa.string()))
    write_table_durably(target / "presses.parquet", table.replace_schema_metadata(encode_metadata(meta)), fsync=False)
    shutil.copyfile(target / "presses.parquet", target / "presses.copy.parquet")
    manifest.update(campaign=name, seed=seed)
    manifest["files_sha256"] = {**manifest["files_sha256"], "presses.parquet": file_sha256(target / "presses.parquet")}
    as_run = manifest.get("protocol_as_run", {}).get("campaign")
    if isinstance(as_run, dict):
        as_run.update(name=name, seed=seed)
    write_manifest(target, manifest, fsync=False)
    return target


_COMMAND_CHILD = """
import json, resource, sys, time
from neatskin.cli import main
t0, c0 = time.perf_counter(), time.process_time()
status = main(sys.argv[1:])
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"status": status, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss}))
"""


def run_command(args: list[str], checkout: Path) -> dict:
    """One `neatskin ...` command in a fresh process of `checkout`: wall, CPU, peak RSS (imports excluded
    from the times, included in the RSS)."""
    done = subprocess.run(
        [sys.executable, "-c", _COMMAND_CHILD, *args],
        env={**os.environ, "PYTHONPATH": str(checkout)},
        cwd=checkout,  # `python -c` puts the working directory first on sys.path, before PYTHONPATH
        capture_output=True,
        text=True,
    )
    lines = done.stdout.strip().splitlines()
    if done.returncode not in (0, 1) or not lines or not lines[-1].startswith("{"):
        raise SystemExit(f"neatskin {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(lines[-1])


def merged(source: Path, copies: int, checkouts: dict[str, Path], baselines_args: list[str], root: Path) -> None:
    """`copies` relabelled copies of `source` merged, validated and reported on, per checkout."""
    root.mkdir(parents=True, exist_ok=True)
    campaigns = root / "campaigns"
    if not campaigns.is_dir():
        t0 = time.perf_counter()
        for k in range(copies):
            copy_campaign(source, campaigns / f"c{k:03d}", k)
        print(f"made {copies} campaigns in {time.perf_counter() - t0:.1f} s", flush=True)
    folders = sorted(str(p) for p in campaigns.iterdir())[:copies]
    print(f"{'checkout':<10}{'command':<12}{'wall s':>9}{'CPU s':>9}{'peak RSS MB':>13}  result")
    for label, checkout in checkouts.items():
        out = root / f"merged-{label}"
        shutil.rmtree(out, ignore_errors=True)
        steps = {
            "merge": ["dataset", "merge", *folders, "-o", str(out)],
            "validate": ["dataset", "validate", str(out)],
            "baselines": ["baselines", str(out), "--no-progress", "--overwrite", *baselines_args],
        }
        for step, args in steps.items():
            r = run_command(args, checkout)
            print(
                f"{label:<10}{step:<12}{r['wall_s']:>9.1f}{r['cpu_s']:>9.1f}{r['peak_rss_mb']:>13.0f}  "
                f"exit {r['status']}",
                flush=True,
            )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", type=int, default=2800)
    parser.add_argument("--memory", help="comma-separated sizes: the writer's peak RSS per size (fresh processes)")
    parser.add_argument("--compare", type=Path, help="another checkout to measure side by side (with --memory)")
    parser.add_argument(
        "--waveform-samples",
        type=int,
        default=5600,
        help="samples per signal per press in the waveform case (28 pairs x 2 sweeps x 100)",
    )
    parser.add_argument(
        "--folder",
        type=Path,
        help="where to write (default: a temp folder on the same disk as /tmp); fsync cost depends on the disk",
    )
    parser.add_argument(
        "--merged",
        type=int,
        metavar="N",
        help="merge N relabelled copies of --source, then validate and report on the merged dataset",
    )
    parser.add_argument("--source", type=Path, help="a finished campaign folder to copy (with --merged)")
    parser.add_argument(
        "--baselines-args",
        default="",
        help="extra arguments of `neatskin baselines` on the merged dataset (with --merged), e.g. "
        "'--models ridge --repeats 1'",
    )
    args = parser.parse_args(argv)
    if args.merged:
        if args.source is None:
            parser.error("--merged needs --source CAMPAIGN_FOLDER (e.g. a paper dry run)")
        checkouts = {"this": REPO, **({"compare": args.compare.resolve()} if args.compare else {})}
        root = (args.folder or Path(tempfile.mkdtemp(prefix="bench-merged-"))).resolve()
        merged(args.source.resolve(), args.merged, checkouts, args.baselines_args.split(), root)
        return 0
    if args.memory:
        checkouts = {"this": REPO, **({"compare": args.compare.resolve()} if args.compare else {})}
        memory([int(n) for n in args.memory.split(",")], checkouts)
        return 0
    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    repeats = 28
    rows = synthetic_rows(layout, -(-args.presses // repeats), repeats, seed=0)[: args.presses]
    root = Path(tempfile.mkdtemp(prefix="bench-datasets-", dir=args.folder))
    try:
        results = [
            run_case(root, "durable", layout, rows, fsync=True, waveform_samples=0),
            run_case(root, "no-fsync", layout, rows, fsync=False, waveform_samples=0),
            run_case(root, "durable+waveforms", layout, rows, fsync=True, waveform_samples=args.waveform_samples),
        ]
    finally:
        shutil.rmtree(root, ignore_errors=True)
    header = (
        f"{'case':<20}{'presses':>8}{'write s':>9}{'ms/press':>10}{'presses/s':>11}{'finalize s':>11}"
        f"{'read parts s':>13}{'read final s':>13}{'validate s':>11}{'MB':>8}"
    )
    print(header)
    for r in results:
        print(
            f"{r['case']:<20}{r['presses']:>8}{r['write_s']:>9.2f}{r['ms_per_press']:>10.2f}"
            f"{r['presses_per_s']:>11.0f}{r['finalize_s']:>11.2f}{r['read_parts_s']:>13.2f}"
            f"{r['read_final_s']:>13.2f}{r['validate_s']:>11.2f}{r['size_mb']:>8.1f}"
        )
    base = results[0]["ms_per_press"]
    print(f"\nfsync cost: durable / no-fsync = {base / results[1]['ms_per_press']:.2f} x per press")
    print(
        f"waveforms ({args.waveform_samples} samples x 3 signals): {results[2]['ms_per_press'] / base:.2f} x "
        f"the per-press cost of features only"
    )
    total = results[0]["write_s"] + results[0]["finalize_s"]
    print(f"writer share of the 60 s dry-run budget (features only): {total:.1f} s = {100 * total / 60:.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: the paper campaign as a dry run, wall time against the rig time its G-code takes, per scene.

Runs protocols/paper.toml (2,800 presses) in several scenes side by side and prints, for each,
the wall time, presses per second, the ratio to the estimated rig time, and the error the
scene costs: the RMS difference of its dR from the most faithful scene's (deformation model,
full waveforms) on the same presses, relative to the RMS of dR.

    python benchmarks/bench_campaign.py                 # all 2,800 presses per scene
    python benchmarks/bench_campaign.py --presses 280   # a quicker look

Scaling (issue 13): 280, 2,800 and 28,000-press dry runs of the paper protocol (10, 100, 1,000 positions),
each in a fresh process so its peak RSS is its own, optionally side by side with another checkout
of the toolkit (e.g. the commit before a change) in the same run:

    python benchmarks/bench_campaign.py --scaling 280,2800,28000 --compare /path/to/other/checkout
    python benchmarks/bench_campaign.py --scaling 2800 --trace      # what holds the memory at finalize

It prints a markdown table (docs/campaigns.md, "Scaling") with each size's ratios to the size before.
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
import pandas as pd

from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign

REPO = Path(__file__).resolve().parent.parent
SCENES = {
    # name: (fidelity, signal, record waveforms)
    "deformation + waveforms (reference)": ("deformation", "waveforms", False),
    "deformation + features": ("deformation", "features", False),
    "network + features": ("network", "features", False),
    "deformation + waveforms, recorded": ("deformation", "waveforms", True),
}


def scene_protocol(root: Path, fidelity: str, signal: str, record: bool) -> Path:
    text = (REPO / "protocols" / "paper.toml").read_text()
    text = text.replace('fidelity = "deformation"', f'fidelity = "{fidelity}"')
    text = text.replace('signal = "features"', f'signal = "{signal}"')
    text = text.replace("waveforms = false", f"waveforms = {'true' if record else 'false'}")
    path = root / f"paper-{fidelity}-{signal}-{int(record)}.toml"
    path.write_text(text)
    return path


_CHILD = """
import json, os, resource, sys, time, tracemalloc
t_start = time.perf_counter()
from neatskin.datasets.writer import CampaignWriter
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign

def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

def rss_mb():
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

trace = sys.argv[3] == "trace"
phases = {"imports_s": time.perf_counter() - t_start, "imports_peak_mb": peak_mb()}
finalize = CampaignWriter.finalize

def timed_finalize(self):
    phases["presses_peak_mb"], phases["rss_before_finalize_mb"] = peak_mb(), rss_mb()
    import pyarrow
    phases["arrow_before_finalize_mb"] = pyarrow.total_allocated_bytes() / 2**20
    if trace:
        phases["top_growth"] = [
            f"{s.size / 2**20:.1f} MB {s.count} blocks {s.traceback[0].filename.split('site-packages/')[-1]}:"
            f"{s.traceback[0].lineno}"
            for s in tracemalloc.take_snapshot().statistics("lineno")[:20]
        ]
    t0 = time.perf_counter()
    try:
        return finalize(self)
    finally:
        phases["finalize_s"], phases["finalize_peak_mb"] = time.perf_counter() - t0, peak_mb()

CampaignWriter.finalize = timed_finalize
if trace:
    tracemalloc.start()
protocol = load_protocol(sys.argv[1])
t0, c0 = time.perf_counter(), time.process_time()
result = run_campaign(protocol, sys.argv[2], dry_run=True, progress=False, report=False)
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
row = {"presses": result.completed, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": peak_mb(), **phases}
row["load_1min"] = os.getloadavg()[0]
print(json.dumps(row))
"""


def scaled_protocol(root: Path, presses: int) -> Path:
    """The paper protocol (28 repeats per position) with presses / 28 positions."""
    if presses % 28:
        raise SystemExit(f"--scaling sizes must be multiples of 28 (the paper's repeats), got {presses}")
    text = (REPO / "protocols" / "paper.toml").read_text().replace("count = 100", f"count = {presses // 28}")
    path = root / f"paper-{presses}.toml"
    path.write_text(text)
    return path


def scaling(sizes: list[int], checkouts: dict[str, Path], trace: bool = False) -> None:
    """Each size in each checkout, in a fresh process: wall, CPU, peak RSS (after imports, after the presses,
    after finalize, at the end: the physical limit and the manifest come after finalize), and each size's ratios to the size before it (linear time: ~10x per 10x presses; flat
    memory: ~1x)."""
    work = Path(tempfile.mkdtemp(prefix="bench-scaling-"))
    rows = []
    try:
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(REPO / "protocols" / sub, work / sub)
        for size in sizes:
            protocol = scaled_protocol(work, size)
            for label, checkout in checkouts.items():
                folder = work / f"run-{label}-{size}"
                env = {**os.environ, "PYTHONPATH": str(checkout)}
                mode = "trace" if trace else "plain"
                done = subprocess.run(
                    [sys.executable, "-c", _CHILD, str(protocol), str(folder), mode],
                    env=env,
                    cwd=checkout,  # `python -c` puts the working directory first on sys.path, before PYTHONPATH
                    capture_output=True,
                    text=True,
                )
                if done.returncode:
                    raise SystemExit(f"{label} {size} failed:\n{done.stderr[-3000:]}")
                row = {"checkout": label, **json.loads(done.stdout.strip().splitlines()[-1])}
                for line in row.pop("top_growth", []):
                    print(f"  {label} {size}: {line}")
                rows.append(row)
                print(json.dumps(row), flush=True)
                shutil.rmtree(folder, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print_scaling_table(pd.DataFrame(rows))


def print_scaling_table(table: pd.DataFrame) -> None:
    """The scaling table as markdown: per checkout and size, the measures and the ratios to the size before."""
    print(
        "\n| checkout | presses | wall s | CPU s | peak RSS MB | peak: presses, finalize MB | finalize s | load | "
        "presses x | wall x | CPU x | RSS x |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label, mine in table.groupby("checkout", sort=False):
        previous = None
        for _, r in mine.iterrows():
            ratios = ["", "", "", ""]
            if previous is not None:
                ratios = [
                    f"{r.presses / previous.presses:.1f}",
                    f"{r.wall_s / previous.wall_s:.2f}",
                    f"{r.cpu_s / previous.cpu_s:.2f}",
                    f"{r.peak_rss_mb / previous.peak_rss_mb:.2f}",
                ]
            print(
                f"| {label} | {int(r.presses):,} | {r.wall_s:.1f} | {r.cpu_s:.1f} | {r.peak_rss_mb:.0f} | "
                f"{r.get('presses_peak_mb', float('nan')):.0f}, {r.get('finalize_peak_mb', float('nan')):.0f} | "
                f"{r.get('finalize_s', float('nan')):.2f} | "
                f"{r.get('load_1min', float('nan')):.1f} | {' | '.join(ratios)} |"
            )
            previous = r


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scaling", help="comma-separated campaign sizes, e.g. 280,2800,28000 (multiples of 28)")
    parser.add_argument("--compare", type=Path, help="another checkout to run side by side (with --scaling)")
    parser.add_argument(
        "--trace",
        action="store_true",
        help="with --scaling: tracemalloc in each run (slower), printing the 20 lines holding most memory "
        "when finalize starts",
    )
    parser.add_argument("--presses", type=int, default=None, help="presses per scene (default: the whole campaign)")
    parser.add_argument(
        "--recorded-presses",
        type=int,
        default=280,
        help="presses for the scene that also writes every sample (default 280; it extrapolates)",
    )
    args = parser.parse_args()
    if args.scaling:
        checkouts = {"this": REPO}
        if args.compare:
            checkouts["compare"] = args.compare.resolve()
        scaling([int(n) for n in args.scaling.split(",")], checkouts, trace=args.trace)
        return
    work = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    try:
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(REPO / "protocols" / sub, work / sub)
        rows, frames = [], {}
        for name, (fidelity, signal, record) in SCENES.items():
            protocol = load_protocol(scene_protocol(work, fidelity, signal, record))
            limit = args.recorded_presses if record else args.presses
            folder = work / f"run-{len(rows)}"
            t0 = time.perf_counter()
            result = run_campaign(protocol, folder, dry_run=True, progress=False, report=False, limit=limit)
            wall = time.perf_counter() - t0
            n = result.completed
            rig_s = result.printer_time_s * n / result.planned
            from neatskin.datasets.reader import read_presses

            df = read_presses(folder).sort_values("press_id").set_index("press_id")
            frames[name] = df.filter(like="dR_ohm_")
            size_mb = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
            rows.append(
                {
                    "scene": name,
                    "presses": n,
                    "wall_s": wall,
                    "presses_per_s": n / wall,
                    "rig_time_h": rig_s / 3600,
                    "x_faster_than_rig": rig_s / wall,
                    "full_campaign_wall_s": wall * result.planned / n,
                    "disk_mb": size_mb,
                }
            )
        ref = frames[next(iter(SCENES))]
        for row in rows:
            dr = frames[row["scene"]].reindex(ref.index).dropna()
            common = ref.loc[dr.index]
            row["dR_error_rel"] = float(np.sqrt(((dr - common) ** 2).to_numpy().mean() / (common**2).to_numpy().mean()))
        table = pd.DataFrame(rows)
        pd.set_option("display.width", 200)
        print(table.to_string(index=False, float_format=lambda v: f"{v:,.3g}"))
        base = table.iloc[0]
        for _, row in table.iloc[1:].iterrows():
            print(
                f"{row.scene}: {base.full_campaign_wall_s / row.full_campaign_wall_s:.2f}x the reference's speed, "
                f"dR error {row.dR_error_rel:.2e} of the dR scale"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

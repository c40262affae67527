"""Benchmark: what the dry run's writer costs per press and at finalize, batched parts against one part per
press, side by side with another checkout (e.g. the commit before batching) in one run.

Two measurements, each in a fresh process per checkout:

- writer alone: synthetic paper rows written without fsync (as a dry run writes), then finalize;
- campaign: the paper protocol as a dry run (`--limit` presses, or all 2,800 with finalize), the time spent
  inside the writer (write_press, flush, finalize) timed in the process: wall time, which also holds the
  waits for the GIL that the simulated printer's thread takes, and the main thread's own CPU time
  (time.thread_time), the writer's cost without those waits or the machine's load.

    python benchmarks/bench_writer_batches.py --presses 2800 --limit 400,2800 --against /tmp/base-checkout

Measured 2026-11-23 against 80806b2 (one part per press), in one run at load average 5.6 to 7.4 on the shared
2-core VM (wall times are inflated by the load; CPU times are the steadier figures):

    writer alone, 2,800 presses:  0.151 ms/press, finalize 0.11 s (11 parts)  vs  6.905 ms/press, 20.42 s (2,800)
    paper dry run, --limit 400:   writer 0.402 ms/press wall, 0.242 CPU       vs  10.143 wall, 3.352 CPU
    paper dry run, 2,800:         writer 0.939 ms/press wall, 0.277 CPU       vs  7.938 wall, 3.039 CPU
                                  finalize 0.75 s wall, 0.22 s CPU             vs  18.62 s wall, 6.05 s CPU
                                  whole run 113.6 s                            vs  134.7 s
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

_WRITER_CHILD = r"""
import json, shutil, sys, tempfile, time
from pathlib import Path
import neatskin.datasets.writer as w
from neatskin.layout import load_layout
from neatskin.skin.synthetic import synthetic_rows
layout = load_layout(sys.argv[1])
n = int(sys.argv[2])
rows = synthetic_rows(layout, -(-n // 28), 28, seed=0)[:n]
batch = w.dry_run_batch_presses(n) if hasattr(w, "dry_run_batch_presses") else 1
kwargs = {"batch_presses": batch} if batch > 1 else {}
folder = Path(tempfile.mkdtemp(prefix="bench-writer-"))
try:
    writer = w.CampaignWriter(folder / "c", layout.pairs, {"seed": 0, "campaign": "synthetic"}, fsync=False, **kwargs)
    t0 = time.perf_counter()
    for row in rows:
        writer.write_press(row)
    if hasattr(writer, "flush"):
        writer.flush()
    t1 = time.perf_counter()
    parts = len(list((folder / "c" / "presses").iterdir()))
    writer.finalize()
    t2 = time.perf_counter()
    writer.close()
    print(json.dumps({"presses": n, "batch": batch, "parts": parts, "write_s": t1 - t0, "finalize_s": t2 - t1}))
finally:
    shutil.rmtree(folder, ignore_errors=True)
"""

_CAMPAIGN_CHILD = r"""
import functools, json, shutil, sys, tempfile, time
import pandas  # pyarrow imports it at the first tz-aware timestamp array: a one-time cost, not the writer's
from pathlib import Path
import neatskin.datasets.writer as w
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
spent = {"write": 0.0, "write_cpu": 0.0, "finalize": 0.0, "finalize_cpu": 0.0}
depth = [0]
def timed(name, fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        depth[0] += 1
        t, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                spent[name] += time.perf_counter() - t
                spent[name + "_cpu"] += time.thread_time() - c
    return wrapper
W = w.CampaignWriter
W.write_press = timed("write", W.write_press)
if hasattr(W, "flush"):
    W.flush = timed("write", W.flush)
W.finalize = timed("finalize", W.finalize)
limit = int(sys.argv[2])
folder = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
try:
    t0 = time.perf_counter()
    result = run_campaign(load_protocol(sys.argv[1]), folder / "c", dry_run=True, progress=False, report=False,
                          limit=limit if limit < 2800 else None)
    wall = time.perf_counter() - t0
    parts = len(list((folder / "c" / "presses").iterdir()))
    print(json.dumps({"presses": result.written_now, "wall_s": wall, "parts_left": parts, **spent}))
finally:
    shutil.rmtree(folder, ignore_errors=True)
"""


def _child(script: str, checkout: Path, *args: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", script, *args],
        env={**os.environ, "PYTHONPATH": str(checkout)},
        cwd=checkout,  # python -c puts the working directory first on sys.path
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", default="2800", help="comma-separated sizes for the writer alone")
    parser.add_argument("--limit", default="400", help="comma-separated presses of the paper dry run (2800: all)")
    parser.add_argument("--against", type=Path, help="another checkout, measured side by side")
    args = parser.parse_args(argv)
    checkouts = {"this": REPO, **({"against": args.against.resolve()} if args.against else {})}
    layout = str(REPO / "protocols" / "skins" / "paper.toml")
    paper = str(REPO / "protocols" / "paper.toml")

    print("writer alone (synthetic paper rows, no fsync)")
    print(f"{'checkout':<9}{'presses':>8}{'batch':>6}{'parts':>7}{'ms/press':>10}{'finalize s':>11}")
    alone: dict[tuple[str, int], dict] = {}
    for n in (int(v) for v in args.presses.split(",")):
        for label, checkout in checkouts.items():
            r = alone[label, n] = _child(_WRITER_CHILD, checkout, layout, str(n))
            print(
                f"{label:<9}{n:>8}{r['batch']:>6}{r['parts']:>7}{1e3 * r['write_s'] / n:>10.3f}{r['finalize_s']:>11.2f}",
                flush=True,
            )
        if "against" in checkouts:
            a, b = alone["this", n], alone["against", n]
            print(
                f"{'ratio':<9}{n:>8}{'':>13}{(a['write_s'] / b['write_s']):>10.2f}{a['finalize_s'] / b['finalize_s']:>11.2f}"
            )

    print("\npaper dry run (time inside the writer, in the campaign process)")
    print(
        f"{'checkout':<9}{'presses':>8}{'wall s':>8}{'write ms/press':>15}{'write CPU ms':>13}{'finalize s':>11}"
        f"{'finalize CPU s':>15}"
    )
    for limit in (int(v) for v in args.limit.split(",")):
        runs = {}
        for label, checkout in checkouts.items():
            r = runs[label] = _child(_CAMPAIGN_CHILD, checkout, paper, str(limit))
            print(
                f"{label:<9}{r['presses']:>8}{r['wall_s']:>8.1f}{1e3 * r['write'] / r['presses']:>15.3f}"
                f"{1e3 * r['write_cpu'] / r['presses']:>13.3f}{r['finalize']:>11.2f}{r['finalize_cpu']:>15.2f}",
                flush=True,
            )
        if "against" in runs:
            a, b = runs["this"], runs["against"]
            fin = (
                f"{a['finalize'] / b['finalize']:>11.2f}{a['finalize_cpu'] / b['finalize_cpu']:>15.2f}"
                if b["finalize"]
                else ""
            )
            print(
                f"{'ratio':<9}{limit:>8}{a['wall_s'] / b['wall_s']:>8.2f}{a['write'] / b['write']:>15.2f}"
                f"{a['write_cpu'] / b['write_cpu']:>13.2f}{fin}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

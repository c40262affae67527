"""Benchmark: the paper dry run with its pair estimates in the skin worker (a second process) against inline, side by side.

Each run is `neatskin campaign run PROTOCOL --dry-run --no-report --quiet` in a child process (the campaign
phase of the README's main job), in three modes, alternating, in one run of this script:

    worker    this checkout, NEATSKIN_SKIN_WORKER=on   (the skin worker computes the estimates)
    inline    this checkout, NEATSKIN_SKIN_WORKER=off  (everything in the main process, as before)
    against   another checkout (--against DIR, e.g. `git worktree add /tmp/base HEAD~2`), as it runs

Per run: wall time; CPU of the main process and of its children (the worker, once reaped); the peak RSS of
the main process and of its largest child (the worker); how long the main process waited for the worker's
estimates (the worker's own count, logged when it closes): near 0, the main process is the critical path; a
large share of the wall time, the worker is (it computes the presses' estimates behind at most 4 presses in
flight). With both worker and inline runs, their rows are compared (R, dR, flags, FSR columns: identical
expected). The load average is printed before and after.

    python benchmarks/bench_dry_worker.py                               # paper protocol, 2,800 presses
    python benchmarks/bench_dry_worker.py --limit 1000 --rounds 3 --against /tmp/base
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# the child: the CLI, then its own and its reaped children's CPU and peak RSS on stderr's last line
_CHILD = r"""
import json, logging, re, resource, sys
waited = []  # the skin worker's closing debug line: how long the main process waited for its estimates
class Waits(logging.Handler):
    def emit(self, record):
        found = re.search(r"the caller waited ([0-9.]+) s", record.getMessage())
        if found:
            waited.append(float(found.group(1)))
worker_log = logging.getLogger("neatskin.sim.skinworker")
worker_log.setLevel(logging.DEBUG)
worker_log.addHandler(Waits())
worker_log.propagate = False
from neatskin.cli import main
code = main(sys.argv[1:])
me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"cpu_main_s": me.ru_utime + me.ru_stime, "cpu_children_s": kids.ru_utime + kids.ru_stime,
                  "rss_main_mb": me.ru_maxrss / 1024, "rss_child_mb": kids.ru_maxrss / 1024,
                  "waited_s": sum(waited) if waited else None}), file=sys.stderr)
sys.exit(code)
"""


def run_once(checkout: Path, protocol: Path, out: Path, limit: int | None, worker: str | None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    env.pop("NEATSKIN_SKIN_WORKER", None)
    if worker is not None:
        env["NEATSKIN_SKIN_WORKER"] = worker
    argv = ["campaign", "run", str(protocol), "--dry-run", "--no-report", "--quiet", "--out", str(out)]
    if limit:
        argv += ["--limit", str(limit)]
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, *argv], env=env, cwd=out.parent, capture_output=True, text=True
    )
    wall = time.perf_counter() - started
    if done.returncode not in (0, 130):  # 130: --limit leaves the campaign interrupted
        raise SystemExit(f"{' '.join(argv)} exited {done.returncode}: {done.stderr[-800:]}")
    return {"wall_s": wall, **json.loads(done.stderr.strip().splitlines()[-1])}


def rows(folder: Path):
    import pandas as pd

    from neatskin.datasets.reader import read_presses

    df = read_presses(folder)
    keep = [c for c in df.columns if c.startswith(("R_ohm", "dR_ohm", "fsr_")) or c in ("press_id", "flags")]
    out = df[keep].copy()
    out["flags"] = out["flags"].map(lambda f: "|".join(f))
    out.attrs = {}
    return pd.DataFrame(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", type=Path, default=REPO / "protocols" / "paper.toml")
    parser.add_argument("--limit", type=int, help="presses per run (default: the whole campaign)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--against", type=Path, help="another checkout, measured as it runs")
    args = parser.parse_args()
    protocol = args.protocol.resolve()
    modes: dict[str, tuple[Path, str | None]] = {"worker": (REPO, "on"), "inline": (REPO, "off")}
    if args.against:
        modes["against"] = (args.against.resolve(), None)
    results: dict[str, list[dict]] = {m: [] for m in modes}
    work = Path(tempfile.mkdtemp(prefix="bench-dry-worker-"))
    load_before = os.getloadavg()
    try:
        for round_ in range(args.rounds):
            for mode, (checkout, worker) in modes.items():
                out = work / f"{mode}-{round_}"
                results[mode].append(run_once(checkout, protocol, out, args.limit, worker))
                print(f"  round {round_ + 1} {mode:<8} {results[mode][-1]['wall_s']:6.1f} s wall", file=sys.stderr)
        load_after = os.getloadavg()
        same = None
        if "worker" in results and "inline" in results:
            import pandas as pd

            last = args.rounds - 1
            try:
                pd.testing.assert_frame_equal(
                    rows(work / f"worker-{last}"), rows(work / f"inline-{last}"), check_exact=True
                )
                same = "identical"
            except AssertionError as exc:
                same = f"DIFFERENT: {str(exc).splitlines()[0]}"
    finally:
        shutil.rmtree(work, ignore_errors=True)
    presses = args.limit or "all"
    print(f"dry run of {protocol.name}, {presses} presses, {os.cpu_count()} cores, {args.rounds} round(s) alternating")
    print(
        "load average (1, 5, 15 min) before {:.2f} {:.2f} {:.2f}, after {:.2f} {:.2f} {:.2f}".format(
            *load_before, *load_after
        )
    )
    print(
        f"{'mode':<8} {'wall s (each round)':<24} {'median':>7} {'cpu main s':>11} {'cpu worker s':>13} "
        f"{'RSS main MB':>12} {'RSS worker MB':>14} {'waited s':>9} {'wall vs inline':>15}"
    )
    inline = statistics.median(r["wall_s"] for r in results["inline"])
    for mode, runs in results.items():
        walls = [r["wall_s"] for r in runs]
        med = statistics.median(walls)
        child_cpu = statistics.median(r["cpu_children_s"] for r in runs)
        child_rss = max(r["rss_child_mb"] for r in runs)
        waits = [r["waited_s"] for r in runs if r.get("waited_s") is not None]
        waited = f"{statistics.median(waits):.1f}" if waits else "-"
        print(
            f"{mode:<8} {' '.join(f'{w:.1f}' for w in walls):<24} {med:>7.1f} "
            f"{statistics.median(r['cpu_main_s'] for r in runs):>11.1f} "
            f"{(f'{child_cpu:.1f}' if mode == 'worker' else '-'):>13} "
            f"{max(r['rss_main_mb'] for r in runs):>12.0f} {(f'{child_rss:.0f}' if mode == 'worker' else '-'):>14} "
            f"{waited:>9} {med / inline:>14.2f}x"
        )
    if same is not None:
        print(f"rows of the last round, worker vs inline (R, dR, flags, FSR): {same}")


if __name__ == "__main__":
    main()

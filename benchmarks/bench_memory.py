"""Benchmark: where the README's main job holds its memory, as a PSS timeline of every process in its tree.

`neatskin campaign run PROTOCOL --dry-run` (the presses, then the baseline report in the same process) runs as a
child; every 0.1 s this script reads /proc/PID/smaps_rollup of the child and each of its descendants (PSS: a page
shared by n processes counts 1/n in each, so the sum is the memory the tree really holds; split into anonymous and
file-backed) and names each process (the main process, the skin worker, multiprocessing's resource tracker, the
report's fit workers). Inside the child a sampler thread (started by a small shim before `neatskin.cli.main`, not
part of the toolkit) records the main thread's innermost neatskin frames and the live thread names, so each row of
the timeline says what the main process was doing. The campaign folder's files (presses.parquet,
physical_limit.parquet, report.md) mark the phases.

    python benchmarks/bench_memory.py                          # the paper protocol, this checkout
    python benchmarks/bench_memory.py --against /tmp/base      # the same on another checkout, alternating
    python benchmarks/bench_memory.py --protocol protocols/smoke.toml --every-s 0.5

Figures: the peak of the tree's summed PSS (a sampled peak: a spike shorter than the interval can be missed), when
it happens, which process held what then, and a timeline (one row per `--every-s` seconds, and the peak's row).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
MARKERS = ("presses.parquet", "physical_limit.parquet", "report.md")

# Runs in the child: a daemon thread samples the main thread's stack (innermost neatskin frames) and the thread
# names into the file named by argv[1], then the CLI runs with the rest of argv.
SHIM = r"""
import sys, threading, time, traceback
out_path, sys.argv = sys.argv[1], ["neatskin", *sys.argv[2:]]
main_ident = threading.main_thread().ident
def _sample():
    with open(out_path, "w", buffering=1) as out:
        while True:
            frame = sys._current_frames().get(main_ident)
            where = []
            for summary in traceback.extract_stack(frame) if frame is not None else ():
                if "/neatskin/" in summary.filename:
                    where.append(summary.filename.rsplit("/neatskin/", 1)[1][:-3] + "." + summary.name)
            names = ",".join(sorted(t.name for t in threading.enumerate() if t.name not in ("MainThread", "memsampler")))
            out.write(f"{time.monotonic():.3f}\t{' > '.join(where[-3:])}\t{names}\n")
            time.sleep(0.05)
threading.Thread(target=_sample, name="memsampler", daemon=True).start()
from neatskin.cli import main
sys.exit(main())
"""


@dataclass
class Sample:
    t_s: float
    pss_kb: dict[int, tuple[int, int, int]]  # pid -> (pss, pss_anon, pss_file)
    names: dict[int, str]
    markers: tuple[str, ...]
    where: str = ""
    threads: str = ""


@dataclass
class Run:
    samples: list[Sample] = field(default_factory=list)
    wall_s: float = 0.0
    ok: bool = True

    def peak(self) -> Sample:
        return max(self.samples, key=lambda s: sum(v[0] for v in s.pss_kb.values()))


def _rollup(pid: int) -> tuple[int, int, int] | None:
    values = {}
    try:
        with open(f"/proc/{pid}/smaps_rollup", "rb") as handle:
            for line in handle:
                key, _, rest = line.partition(b":")
                if key in (b"Pss", b"Pss_Anon", b"Pss_File"):
                    values[key] = int(rest.split()[0])
    except (OSError, ValueError):
        return None
    return values.get(b"Pss", 0), values.get(b"Pss_Anon", 0), values.get(b"Pss_File", 0)


def _name(pid: int, root: int, campaign_done: bool) -> str:
    if pid == root:
        return "main"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            cmd = handle.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return "?"
    if "resource_tracker" in cmd:
        return "resource-tracker"
    if "loky" in cmd or "joblib" in cmd:
        return "fit-worker"
    if "spawn_main" in cmd or "forkserver" in cmd:  # the same command line: told apart by when they start
        return "fit-worker" if campaign_done else "skin-worker"
    return cmd.split(" ", 2)[-1][:30]


def _tree(root: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as handle:
                ppid = int(handle.read().rsplit(b")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo.extend(children.get(pid, ()))
    return out


def measure(checkout: Path, protocol: Path, work: Path, every_s: float = 0.1, report: Path | None = None) -> Run:
    """The main job on one checkout (or with `report`, that campaign's baseline report alone, written to a fresh
    folder), its tree sampled every `every_s` seconds."""
    try:
        protocol = checkout / protocol.relative_to(REPO.resolve())
    except ValueError:
        pass
    folder, trace = work / "main", work / "where.tsv"
    env = dict(os.environ, PYTHONPATH=str(checkout))
    argv = [sys.executable, "-c", SHIM, str(trace)]
    if report is None:
        argv += ["campaign", "run", str(protocol), "--dry-run", "--quiet", "--out", str(folder)]
    else:
        argv += ["baselines", str(report), "--split", "both", "--quiet", "--out", str(folder)]
    run, names = Run(), {}
    started = time.monotonic()
    child = subprocess.Popen(argv, cwd=work, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    while child.poll() is None:
        now = time.monotonic()
        sizes = {}
        markers = tuple(m for m in MARKERS if (folder / m).exists())
        for pid in _tree(child.pid):
            rollup = _rollup(pid)
            if rollup is not None:
                sizes[pid] = rollup
                names.setdefault(pid, _name(pid, child.pid, report is not None or MARKERS[0] in markers))
        run.samples.append(Sample(now, sizes, {p: names[p] for p in sizes}, markers))
        time.sleep(max(0.0, every_s - (time.monotonic() - now)))
    run.wall_s = time.monotonic() - started
    err = child.stderr.read().decode(errors="replace") if child.stderr else ""
    run.ok = child.returncode == 0
    if not run.ok:
        print(f"  ! exited {child.returncode}: {err.strip()[-600:]}", file=sys.stderr)
    _attach_where(run, trace)
    for sample in run.samples:
        sample.t_s -= started
    return run


def _attach_where(run: Run, trace: Path) -> None:
    try:
        rows = [line.rstrip("\n").split("\t") for line in trace.read_text().splitlines()]
    except OSError:
        return
    rows = [(float(r[0]), r[1], r[2] if len(r) > 2 else "") for r in rows if r and r[0]]
    i = 0
    for sample in run.samples:
        while i + 1 < len(rows) and rows[i + 1][0] <= sample.t_s:
            i += 1
        if rows and rows[i][0] <= sample.t_s + 0.1:
            sample.where, sample.threads = rows[i][1], rows[i][2]


def _mb(kb: float) -> str:
    return f"{kb / 1024:.0f}"


def _by_name(sample: Sample) -> dict[str, int]:
    out: dict[str, int] = {}
    for pid, (pss, _, _) in sample.pss_kb.items():
        out[sample.names[pid]] = out.get(sample.names[pid], 0) + pss
    return out


def report(label: str, run: Run, every_s: float) -> None:
    peak = run.peak()
    total = sum(v[0] for v in peak.pss_kb.values())
    print(f"\n== {label}: wall {run.wall_s:.1f} s, {'ok' if run.ok else 'FAILED'}, {len(run.samples)} samples")
    print(f"peak tree PSS {_mb(total)} MB at t = {peak.t_s:.1f} s; markers then: {', '.join(peak.markers) or '-'}")
    print(f"  main thread in: {peak.where or '?'}")
    print(f"  threads: {peak.threads or '-'}")
    for pid, (pss, anon, filed) in sorted(peak.pss_kb.items(), key=lambda kv: -kv[1][0]):
        print(f"  {peak.names[pid]:<18} pid {pid:<7} PSS {_mb(pss):>5} MB (anon {_mb(anon):>5}, file {_mb(filed):>4})")
    columns = sorted({n for s in run.samples for n in s.names.values()}, key=lambda n: (n != "main", n))
    print(f"{'t s':>6} {'tree MB':>8} " + " ".join(f"{c[:12]:>12}" for c in columns) + "  markers / main thread in")
    next_t, last_markers = 0.0, ()
    for sample in run.samples:
        if sample.t_s < next_t and sample is not peak and sample.markers == last_markers:
            continue
        next_t = sample.t_s + every_s
        last_markers = sample.markers
        by = _by_name(sample)
        mark = "*" if sample is peak else " "
        row = f"{sample.t_s:>6.1f} {_mb(sum(by.values())):>7}{mark} " + " ".join(
            f"{_mb(by.get(c, 0)):>12}" for c in columns
        )
        print(f"{row}  [{len(sample.markers)}] {sample.where[-90:]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", type=Path, default=REPO / "protocols" / "paper.toml")
    parser.add_argument("--against", type=Path, help="another checkout of the toolkit to measure side by side")
    parser.add_argument("--rounds", type=int, default=1, help="alternating rounds per checkout")
    parser.add_argument("--every-s", type=float, default=2.0, help="timeline row interval (sampling stays 0.1 s)")
    parser.add_argument("--quiet", action="store_true", help="only the peaks, no timeline")
    parser.add_argument("--keep", action="store_true", help="keep each run's folder (to compare the outputs)")
    parser.add_argument("--report", type=Path, help="a complete campaign folder: measure its baseline report alone")
    args = parser.parse_args()
    checkouts = {"this": REPO}
    if args.against:
        checkouts["against"] = args.against.resolve()
    load = os.getloadavg()
    peaks: dict[str, list[float]] = {name: [] for name in checkouts}
    for round_ in range(args.rounds):
        order = list(checkouts.items())
        for name, checkout in order if round_ % 2 == 0 else order[::-1]:
            work = Path(tempfile.mkdtemp(prefix=f"bench-memory-{name}-"))
            try:
                run = measure(checkout, args.protocol.resolve(), work, report=args.report)
            finally:
                if args.keep:
                    print(f"{name} round {round_ + 1}: kept {work}")
                else:
                    shutil.rmtree(work, ignore_errors=True)
            peaks[name].append(sum(v[0] for v in run.peak().pss_kb.values()) / 1024)
            if not args.quiet:
                report(f"{name} ({checkout}), round {round_ + 1}", run, args.every_s)
            else:
                print(f"{name} round {round_ + 1}: peak {peaks[name][-1]:.0f} MB, wall {run.wall_s:.1f} s")
    after = os.getloadavg()
    print(
        f"\nload average before {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, after {after[0]:.2f} {after[1]:.2f} {after[2]:.2f}"
    )
    for name, values in peaks.items():
        print(f"peak tree PSS MB, {name}: " + " ".join(f"{v:.0f}" for v in values))


if __name__ == "__main__":
    threading.current_thread().name = "bench"
    main()

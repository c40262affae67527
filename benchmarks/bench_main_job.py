"""Benchmark: the README's main job end to end, by phase, with wall time, CPU time and peak memory.

The main job is one command, `neatskin campaign run protocols/paper.toml --dry-run` (the
install excluded). Its phases are measured as the commands a user can also run on their own:

    campaign   neatskin campaign run PROTOCOL --dry-run --no-report   (the presses, finalize, bound)
    report     neatskin baselines CAMPAIGN --split both                (the baseline report, as the main job makes it)
    main job   neatskin campaign run PROTOCOL --dry-run                (both, as the README runs it)

Each phase is a child process; its CPU time and peak RSS come from the kernel's accounting of that
child (os.wait4), so nothing of this script is counted. The kernel's peak RSS is that of the largest
single process (the child or one of its descendants); the dry run's skin worker and the report's fit
workers run beside the main process, so the table also gives the peak of the whole process tree's
summed PSS (proportional set size: a page shared by n processes, such as the libraries' code or the
report's memory-mapped features, counts 1/n in each, so the sum is the memory the tree really holds),
sampled every 0.1 s from /proc/PID/smaps_rollup (a sampled peak: a shorter spike can be missed). With --against DIR the same phases run on
another checkout of the toolkit (e.g. the previous commit: `git worktree add /tmp/prev HEAD~1`)
side by side, alternating, and the table gives the ratio.

    python benchmarks/bench_main_job.py                        # the paper protocol, this checkout
    python benchmarks/bench_main_job.py --protocol protocols/smoke.toml
    python benchmarks/bench_main_job.py --against /tmp/prev    # side by side with another checkout
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
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Measurement:
    wall_s: float
    cpu_s: float
    peak_rss_mb: float
    ok: bool
    tree_pss_mb: float = 0.0  # peak of the process tree's summed PSS, sampled


def _pss_kb(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/smaps_rollup", "rb") as handle:
            for line in handle:
                if line.startswith(b"Pss:"):
                    return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def _tree_pss_mb(root: int) -> float:
    """Summed PSS (MB) of `root` and its descendants now, from /proc (Linux; 0 elsewhere)."""
    children: dict[int, list[int]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return 0.0
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as handle:
                fields = handle.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(entry))  # fields[1] is the ppid
    total_kb, todo = 0, [root]
    while todo:
        pid = todo.pop()
        total_kb += _pss_kb(pid)
        todo.extend(children.get(pid, ()))
    return total_kb / 1024.0


class _TreeSampler(threading.Thread):
    def __init__(self, root: int, every_s: float = 0.1) -> None:
        super().__init__(daemon=True)
        self.root, self.every_s, self.peak_mb = root, every_s, 0.0
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.wait(self.every_s):
            self.peak_mb = max(self.peak_mb, _tree_pss_mb(self.root))


def run_child(argv: list[str], checkout: Path, cwd: Path) -> Measurement:
    """Run one command as a child with `checkout` first on the import path; its own wall, CPU and peak RSS."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    started = time.perf_counter()
    child = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    sampler = _TreeSampler(child.pid)
    sampler.start()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - started
    sampler.done.set()
    sampler.join()
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        err = child.stderr.read().decode(errors="replace") if child.stderr else ""
        print(f"  ! {' '.join(argv[2:])} exited {child.returncode}: {err.strip()[-400:]}", file=sys.stderr)
    if child.stderr:
        child.stderr.close()
    cpu = usage.ru_utime + usage.ru_stime
    return Measurement(wall, cpu, usage.ru_maxrss / 1024.0, child.returncode == 0, sampler.peak_mb)


PHASES = ("campaign", "report", "main job")


def phases(checkout: Path, protocol: Path, work: Path, only: tuple[str, ...] = PHASES) -> dict[str, Measurement]:
    """The phases on one checkout (all three, or `only` these), each in a fresh campaign folder. A protocol inside
    this checkout is run from the same relative path in the other one (its own protocols, which its schema
    accepts). The report needs the campaign phase's folder: asking for it runs the campaign too."""
    try:
        protocol = checkout / protocol.relative_to(REPO.resolve())
    except ValueError:
        pass
    neatskin = [sys.executable, "-m", "neatskin"]
    out = {}
    campaign = work / "campaign"
    if "campaign" in only or "report" in only:
        out["campaign"] = run_child(
            [
                *neatskin,
                "campaign",
                "run",
                str(protocol),
                "--dry-run",
                "--no-report",
                "--quiet",
                "--out",
                str(campaign),
            ],
            checkout,
            work,
        )
    if "report" in only:
        out["report"] = run_child([*neatskin, "baselines", str(campaign), "--split", "both"], checkout, work)
    if "main job" in only:
        out["main job"] = run_child(
            [*neatskin, "campaign", "run", str(protocol), "--dry-run", "--quiet", "--out", str(work / "main")],
            checkout,
            work,
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", type=Path, default=REPO / "protocols" / "paper.toml")
    parser.add_argument("--against", type=Path, help="another checkout of the toolkit to measure side by side")
    parser.add_argument("--rounds", type=int, default=1, help="alternating rounds per checkout (best is kept)")
    parser.add_argument(
        "--phases", nargs="+", choices=PHASES, default=list(PHASES), help="only these phases (e.g. campaign)"
    )
    args = parser.parse_args()
    protocol = args.protocol.resolve()
    checkouts = {"this": REPO}
    if args.against:
        checkouts["against"] = args.against.resolve()
    best: dict[str, dict[str, Measurement]] = {name: {} for name in checkouts}
    load_before = os.getloadavg()
    walls: dict[str, dict[str, list[float]]] = {name: {} for name in checkouts}
    for round_ in range(args.rounds):
        order = list(checkouts.items())
        for name, checkout in order if round_ % 2 == 0 else order[::-1]:  # who goes first alternates too
            work = Path(tempfile.mkdtemp(prefix=f"bench-main-{name}-"))
            try:
                for phase, m in phases(checkout, protocol, work, tuple(args.phases)).items():
                    walls[name].setdefault(phase, []).append(m.wall_s)
                    kept = best[name].get(phase)
                    if kept is None or m.wall_s < kept.wall_s:
                        best[name][phase] = m
            finally:
                shutil.rmtree(work, ignore_errors=True)
    load_after = os.getloadavg()
    print(f"main job on {protocol.name}, {os.cpu_count()} cores, best of {args.rounds} round(s)")
    print(
        f"load average (1, 5, 15 min) before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}, "
        f"after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}"
    )
    header = (
        f"{'checkout':<9} {'phase':<10} {'wall s':>8} {'cpu s':>8} {'peak RSS MB':>12} {'tree PSS MB':>12} {'ok':>4}"
    )
    if args.against:
        header += f" {'wall vs against':>16}"
    print(header)
    for name in checkouts:
        for phase, m in best[name].items():
            line = (
                f"{name:<9} {phase:<10} {m.wall_s:>8.1f} {m.cpu_s:>8.1f} {m.peak_rss_mb:>12.0f} "
                f"{m.tree_pss_mb:>12.0f} {'yes' if m.ok else 'NO':>4}"
            )
            if args.against and name == "this":
                other = best["against"].get(phase)
                line += f" {m.wall_s / other.wall_s:>15.2f}x" if other else ""
            print(line)
    print("wall s of every round, in order (best above):")
    for name in checkouts:
        for phase, values in walls[name].items():
            print(f"  {name:<9} {phase:<10} " + " ".join(f"{w:.1f}" for w in values))


if __name__ == "__main__":
    main()

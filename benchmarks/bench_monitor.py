"""Benchmark: a dry-run campaign's wall time with and without a monitor attached, side by side in one run.

"With monitor" = `neatskin monitor` serving the campaign folder in its own process, plus a second process
polling its /api/state as the page does (every --poll-s seconds, default 1; the page's default). Runs
alternate (without, with, without, ...) so machine load drifts into both columns alike; the table gives each
run, the median of each column and their ratio (target: under 5 % slower).

    python benchmarks/bench_monitor.py                      # paper protocol, 300 presses, 3 runs each
    python benchmarks/bench_monitor.py --presses 100 --runs 2 --poll-s 0.25
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.tomlfile import resolve_path

REPO = Path(__file__).resolve().parent.parent
POLLER = """
import sys, time, urllib.request
url, period = sys.argv[1], float(sys.argv[2])
n = 0
while True:
    try:
        urllib.request.urlopen(url, timeout=10).read(); n += 1
    except OSError:
        pass
    time.sleep(period)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_listening(port: int, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"monitor never listened on {port}")


def one_run(
    protocol_path: Path, folder: Path, presses: int, monitor: bool, poll_s: float
) -> tuple[float, float, float]:
    """(wall s, the campaign's CPU s, the monitor's and poller's CPU s) of one run."""
    protocol = load_protocol(protocol_path)
    children0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    procs: list[subprocess.Popen] = []
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    try:
        if monitor:
            folder.mkdir(parents=True)
            port = free_port()
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "neatskin", "monitor", str(folder), "--port", str(port)],
                    stdout=subprocess.DEVNULL,
                    env=env,
                )
            )
            wait_listening(port)
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-c", POLLER, f"http://127.0.0.1:{port}/api/state", str(poll_s)], env=env
                )
            )
        t0, cpu0 = time.perf_counter(), time.process_time()
        result = run_campaign(protocol, folder, progress=False, report=False, limit=presses)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        assert result.completed == presses, result
    finally:
        for proc in procs:
            proc.terminate()
            proc.wait(30)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    side_cpu = (children.ru_utime - children0.ru_utime) + (children.ru_stime - children0.ru_stime)
    return wall, cpu, side_cpu


def startup_cpu_s(folder: Path) -> float:
    """CPU of starting `neatskin monitor` (imports) and its poller's first request, then stopping them."""
    folder.mkdir(parents=True, exist_ok=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    monitor = subprocess.Popen(
        [sys.executable, "-m", "neatskin", "monitor", str(folder), "--port", str(port)],
        stdout=subprocess.DEVNULL,
        env=env,
    )
    wait_listening(port)
    poller = subprocess.Popen([sys.executable, "-c", POLLER, f"http://127.0.0.1:{port}/api/state", "1000"], env=env)
    time.sleep(2.0)
    for proc in (poller, monitor):
        proc.terminate()
        proc.wait(30)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", default="protocols/paper.toml")
    parser.add_argument("--presses", type=int, default=300)
    parser.add_argument("--runs", type=int, default=3, help="runs per column (alternating)")
    parser.add_argument("--poll-s", type=float, default=1.0, help="the page's polling period")
    args = parser.parse_args()
    protocol_path = resolve_path(args.protocol)
    work = Path(tempfile.mkdtemp(prefix="bench-monitor-"))
    runs: dict[bool, list[tuple[float, float, float]]] = {False: [], True: []}
    try:
        one_run(protocol_path, work / "warm-up", min(args.presses, 20), False, args.poll_s)  # imports, caches
        for k in range(args.runs):
            for monitor in (False, True) if k % 2 == 0 else (True, False):
                folder = work / f"run-{k}-{int(monitor)}"
                runs[monitor].append(one_run(protocol_path, folder, args.presses, monitor, args.poll_s))
                shutil.rmtree(folder, ignore_errors=True)
        startup = float(np.median([startup_cpu_s(work / "idle") for _ in range(2)]))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load = os.getloadavg()[0]
    print(
        f"{protocol_path.name}, {args.presses} presses per run, page polling every {args.poll_s} s, "
        f"{os.cpu_count()} CPUs, load average {load:.1f} at the end"
    )
    print(
        f"{'run':>4} | {'wall without':>12} {'wall with':>10} | {'campaign CPU without':>20} {'with':>6} | {'monitor+poller CPU':>18}"
    )
    for k in range(args.runs):
        (w0, c0, _), (w1, c1, m1) = runs[False][k], runs[True][k]
        print(f"{k + 1:>4} | {w0:>11.2f}s {w1:>9.2f}s | {c0:>19.2f}s {c1:>5.2f}s | {m1:>17.2f}s")
    med = {m: np.median(np.array(runs[m]), axis=0) for m in (False, True)}
    print(
        f"{'med':>4} | {med[False][0]:>11.2f}s {med[True][0]:>9.2f}s | {med[False][1]:>19.2f}s "
        f"{med[True][1]:>5.2f}s | {med[True][2]:>17.2f}s"
    )
    walls = {m: [r[0] for r in runs[m]] for m in (False, True)}
    spread = {m: (max(walls[m]) - min(walls[m])) / np.median(walls[m]) * 100 for m in (False, True)}
    print(
        f"wall with / without = {med[True][0] / med[False][0]:.3f} "
        f"(spread (max - min) / median: without {spread[False]:.0f} %, with {spread[True]:.0f} %)"
    )
    steady = max(med[True][2] - startup, 0.0)
    print(
        f"monitor + poller CPU: {med[True][2]:.2f} s, of which {startup:.2f} s is starting them (imports); the rest, "
        f"{steady:.2f} s, is {steady / med[True][0] * 100:.1f} % of a CPU over the campaign's wall time and "
        f"{steady / med[True][1] * 100:.1f} % of the campaign's own CPU (the slowdown if both shared one core)"
    )


if __name__ == "__main__":
    main()

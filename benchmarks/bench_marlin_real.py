"""Time per line on the real Marlin firmware: this driver against Printrun's printcore, side by side in one run.

Run: PYTHONPATH=. /work/venv/bin/python benchmarks/bench_marlin_real.py [--lines 2000] [--rounds 3]
     [--build marlin-native|marlin-native-advok] [--in-flight 1]

The firmware is ../shared/marlin's native build (sim/realmarlin.py finds it) behind our relay on a
pty; each host streams the same program of quick commands (`G90`/`G21`/`M118 E1`, no motion, so
the time is the serial round trip and the hosts' own cost, not steppers). The rounds alternate
the two hosts, each round on a fresh firmware, so both see the same machine load; the table gives
the median and range of the rounds in ms per line, and the load average before and after.
The driver confirms its batch with a probe (as `printer send` does); printcore is Printrun 2.2.0
(`pip install --no-deps printrun==2.2.0`), polled for the end of its print every 5 ms.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))

from neatskin.marlin.driver import DriverConfig, MarlinDriver  # noqa: E402
from neatskin.marlin.replies import PROBE_TAG  # noqa: E402
from neatskin.sim.realmarlin import PLAIN, FirmwareRelay, find_marlin_dir  # noqa: E402


def program(n: int) -> list[str]:
    quick = ["G90", "G21", "M118 E1 tick"]
    return [quick[i % 3] for i in range(n)]


def executed_count(relay: FirmwareRelay) -> int:
    """The firmware's own count of lines run: its ok replies (M111 is off: the echo would double the bytes)."""
    return sum(1 for line in relay.replies() if line.startswith(b"ok"))


def run_driver(binary: Path, lines: list[str], in_flight: int) -> float:
    with FirmwareRelay(binary) as relay:
        config = DriverConfig(boot_timeout_s=0.1, confirm_batches=True, max_in_flight=in_flight)
        driver = MarlinDriver.open(relay.path, config=config)
        try:
            driver.connect()
            start = time.perf_counter()
            driver.send_lines(lines)
            elapsed = time.perf_counter() - start
        finally:
            driver.close()
        echoed = [line for line in relay.replies() if PROBE_TAG.encode() in line]
        assert echoed, "the confirming probe was never echoed"
    return elapsed / len(lines)


def run_printcore(binary: Path, lines: list[str]) -> float:
    from printrun import gcoder
    from printrun.printcore import printcore

    with FirmwareRelay(binary) as relay:
        host = printcore(relay.path, 115200)
        try:
            end = time.monotonic() + 60  # its first M105 round trip; slow on a loaded machine
            while not host.online and time.monotonic() < end:
                time.sleep(0.005)
            if not host.online:
                raise RuntimeError("printcore did not come online")
            code = gcoder.LightGCode(lines)
            start = time.perf_counter()
            host.startprint(code)
            end = time.monotonic() + 600
            while host.printing and time.monotonic() < end:
                time.sleep(0.005)
            elapsed = time.perf_counter() - start
        finally:
            host.disconnect()
    return elapsed / len(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--build", default=PLAIN)
    parser.add_argument("--in-flight", type=int, default=1, help="the driver's max_in_flight (>1 needs advok)")
    args = parser.parse_args()
    folder = find_marlin_dir(HERE)
    if folder is None:
        print("no real firmware: shared/marlin beside the repository (or $NEATSKIN_MARLIN_DIR)", file=sys.stderr)
        return 2
    binary = folder / args.build
    lines = program(args.lines)
    load_before = os.getloadavg()
    runs: dict[str, list[float]] = {"driver": [], "printcore": []}
    for k in range(args.rounds):
        order = ["driver", "printcore"] if k % 2 == 0 else ["printcore", "driver"]
        for host in order:
            per_line = run_driver(binary, lines, args.in_flight) if host == "driver" else run_printcore(binary, lines)
            runs[host].append(per_line * 1000)
            print(f"round {k + 1} {host}: {per_line * 1000:.3f} ms/line", file=sys.stderr)
    load_after = os.getloadavg()
    print(f"real Marlin ({args.build}), {args.lines} lines per run, {args.rounds} rounds alternating")
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    print("| host | ms per line, median | range |")
    print("|---|---:|---:|")
    for host, values in runs.items():
        print(f"| {host} | {statistics.median(values):.3f} | {min(values):.3f} - {max(values):.3f} |")
    ratio = statistics.median(runs["printcore"]) / statistics.median(runs["driver"])
    print(f"printcore / driver: {ratio:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

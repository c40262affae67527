"""The simulated printer's hot path, side by side: this tree's simulator against another tree's, in one run.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_sim_printer.py --base /tmp/base [--lines 2000] [--rounds 3]
     [--presses 400] [--only-presses]

First table: the dry run's own G-code path, per paper press (5 send_lines, 15 lines): the simulated
printer on a pty served from a thread of the driver's process, with a wire log, as `campaign run
--dry-run` sets it up; one line in flight, and pipelined (`ok N P B` and up to 4 lines in flight).
Wall ms, CPU ms (process_time: all threads) and context switches per press, median of the rounds.

`--base` is a checkout of the commit to compare with (e.g. `git worktree add /tmp/base 74b806b`).
Every peer runs in its own process (its own GIL), as a real printer does: `neatskin sim printer
--time virtual` started from each tree with that tree on PYTHONPATH, and a bare echo peer that
answers every line with `ok` (the pty's round-trip limit). The hosts are this tree's: the bare
host loop (write a line, read to `ok`) and MarlinDriver.send_lines, one line in flight. The
rounds alternate base and this tree, so both see the same machine load; each row is the best
round. `sim core` is the firmware model alone (no I/O), run in a subprocess of each tree and
timed in CPU seconds (process_time), so that the machine's load does not enter it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import serial

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))

sys.path.insert(0, str(HERE / "benchmarks"))

from bench_marlin import ECHO_SCRIPT, _read_ok, framed_lines  # noqa: E402

from neatskin.marlin.driver import DriverConfig, MarlinDriver  # noqa: E402

CONFIG = DriverConfig(boot_timeout_s=0.05, motion_time_scale=0.0)
CORE = """
import sys, time
from neatskin.gcode.parse import checksum
from neatskin.gcode.profile import load_printer_profile
from neatskin.sim.firmware import MarlinCore
from neatskin.tomlfile import resolve_path
n = int(sys.argv[1])
core = MarlinCore(load_printer_profile(resolve_path("protocols/printers/paper.toml")))
core.receive(b"G28\\n"); core.step(); core.take_output()
core.receive(b"N0 M110 N0*125\\n"); core.step()
lines = []
for i in range(n):
    body = f"N{i + 1} G1 X{10 + i % 100} Y{20 + i % 50} F6000"
    lines.append(f"{body}*{checksum(body)}\\n".encode())
start = time.process_time()
for line in lines:
    core.receive(line); core.step(); core.take_output()
print(n / (time.process_time() - start))
"""

# The dry run's own set-up: the simulated printer on a pty served from a thread of the driver's process (it
# shares the GIL), a wire log, and the paper press's 5 send_lines calls (travel, descend, press, hold, lift).
PRESSES = """
import json, os, resource, sys, tempfile, time
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan
from neatskin.sim.printer import SimulatedPrinter
n, mode = int(sys.argv[1]), sys.argv[2]
protocol = load_protocol("protocols/paper.toml")
plan = build_plan(protocol)
pipelined = mode == "pipelined"
printer = SimulatedPrinter(protocol.printer, seed=1, time_mode="virtual", advanced_ok=pipelined)
config = DriverConfig(motion_time_scale=0.0, max_in_flight=4 if pipelined else 1)
with tempfile.TemporaryDirectory() as tmp:
    driver = MarlinDriver.open(printer.start_pty(), config=config, wire_log=os.path.join(tmp, "wire.log"))
    driver.connect(boot_timeout_s=3.0)
    driver.send_lines(plan.program.preamble)
    hold = (f"G4 P{int(round(plan.hold_s * 1000))}", "M400")
    usage, cpu, start = resource.getrusage(resource.RUSAGE_SELF), time.process_time(), time.perf_counter()
    for block in plan.program.presses[:n]:
        for phase in block.phases:
            driver.send_lines(phase.lines)
            if phase.name == "press":
                driver.send_lines(hold)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    after = resource.getrusage(resource.RUSAGE_SELF)
    switches = (after.ru_nvcsw - usage.ru_nvcsw) + (after.ru_nivcsw - usage.ru_nivcsw)
    driver.close()
printer.stop()
print(json.dumps({"wall_ms": 1e3 * wall / n, "cpu_ms": 1e3 * cpu / n, "switches": switches / n}))
"""


def presses(tree: Path, n: int, mode: str) -> dict[str, float]:
    """Per press of the paper dry run's G-code path in `tree`: wall ms, CPU ms, context switches."""
    import json

    out = subprocess.run(
        [sys.executable, "-c", PRESSES, str(n), mode], cwd=tree, env=_env(tree), capture_output=True, text=True
    )
    if out.returncode:
        raise RuntimeError(f"{tree}: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout)


def press_table(trees: dict[str, Path], n: int, rounds: int) -> None:
    """The paper press through driver, pty and simulated printer, side by side, rounds alternating trees."""
    import statistics

    runs: dict[tuple[str, str], list[dict[str, float]]] = {}
    for _ in range(rounds):
        for mode in ("one in flight", "pipelined"):
            for name, tree in trees.items():
                runs.setdefault((mode, name), []).append(presses(tree, n, mode.split()[0]))
    print(f"paper presses ({n} per run, 15 lines in 5 send_lines each), in-process printer on a pty, wire log;")
    print(f"median (min-max) of {rounds} alternating rounds; pipelined = `ok N P B` + max_in_flight=4")
    print(
        f"{'':16s} {'tree':>5s} {'wall ms/press':>20s} {'CPU ms/press':>20s} {'switches/press':>15s} {'wall this/base':>14s}"
    )
    for (mode, name), results in runs.items():
        cells = []
        for key in ("wall_ms", "cpu_ms"):
            values = [r[key] for r in results]
            cells.append(f"{statistics.median(values):6.3f} ({min(values):.3f}-{max(values):.3f})")
        switches = statistics.median(r["switches"] for r in results)
        base = runs.get((mode, "base"))
        ratio = ""
        if name == "this" and base:
            ratio = f"{statistics.median(r['wall_ms'] for r in results) / statistics.median(r['wall_ms'] for r in base):14.2f}"
        print(f"{mode:16s} {name:>5s} {cells[0]:>20s} {cells[1]:>20s} {switches:15.1f} {ratio:>14s}")
    print()


def _env(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree)}


class Peer:
    """A peer process serving a pty; `.path` is what a host opens."""

    def __init__(self, tree: Path, kind: str) -> None:
        argv = (
            [sys.executable, "-c", ECHO_SCRIPT]
            if kind == "echo"
            else [sys.executable, "-m", "neatskin", "sim", "printer"]
        )
        if kind != "echo":
            argv += ["--time", "virtual"]
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=tree, env=_env(tree)
        )
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()

    def cpu_s(self) -> float:
        """The peer process's CPU time so far (user + system, from /proc)."""
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=5)


def bare_host(peer: Peer, lines: list[bytes], hello: list[bytes]) -> tuple[float, float]:
    """(lines per second, peer CPU seconds per line) of the simplest host loop."""
    port = serial.Serial(peer.path, 115200, timeout=1.0)
    try:
        port.reset_input_buffer()
        for line in hello:
            port.write(line)
            _read_ok(port)
        cpu, start = peer.cpu_s(), time.perf_counter()
        for line in lines:
            port.write(line)
            _read_ok(port)
        wall = time.perf_counter() - start
        return len(lines) / wall, (peer.cpu_s() - cpu) / len(lines)
    finally:
        port.close()


def driver_rate(peer: Peer, commands: list[str]) -> tuple[float, float]:
    driver = MarlinDriver(serial.serial_for_url(peer.path, do_not_open=True), config=CONFIG)
    try:
        driver.connect()
        driver.send("G28")
        cpu, start = peer.cpu_s(), time.perf_counter()
        driver.send_lines(commands)
        wall = time.perf_counter() - start
        return len(commands) / wall, (peer.cpu_s() - cpu) / len(commands)
    finally:
        driver.close()


def with_peer(tree: Path, kind: str, fn) -> tuple[float, float]:
    peer = Peer(tree, kind)
    try:
        return fn(peer)
    finally:
        peer.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="a checkout of the commit to compare with")
    parser.add_argument("--lines", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds; each row is the best")
    parser.add_argument("--presses", type=int, default=400, help="paper presses per run of the press table")
    parser.add_argument("--only-presses", action="store_true", help="print the press table only")
    args = parser.parse_args()
    trees = {"base": args.base.resolve(), "this": HERE}
    press_table(trees, args.presses, args.rounds)
    if args.only_presses:
        return 0
    lines = framed_lines(args.lines)
    commands = [f"G1 X{10 + i % 100} Y{20 + i % 50} F6000" for i in range(args.lines)]
    hello = [b"N0 M110 N0*125\n", b"G28\n"]
    rows: dict[tuple[str, str], float] = {}
    cpu: dict[tuple[str, str], float] = {}

    def record(key: tuple[str, str], result: tuple[float, float]) -> None:
        rows[key] = max(rows.get(key, 0.0), result[0])
        cpu[key] = min(cpu.get(key, float("inf")), result[1])

    for _ in range(args.rounds):
        record(("echo limit (bare host, echo peer)", ""), with_peer(HERE, "echo", lambda p: bare_host(p, lines, [])))
        for name, tree in trees.items():
            record(("bare host vs sim printer", name), with_peer(tree, "sim", lambda p: bare_host(p, lines, hello)))
            record(("driver vs sim printer", name), with_peer(tree, "sim", lambda p: driver_rate(p, commands)))
            out = subprocess.run(
                [sys.executable, "-c", CORE, str(args.lines)], cwd=tree, env=_env(tree), capture_output=True, text=True
            )
            rate = float(out.stdout.strip())
            record(("sim core only (no I/O)", name), (rate, 1 / rate))
    limit = rows[("echo limit (bare host, echo peer)", "")]
    print(f"{args.lines} lines, one in flight, best of {args.rounds} alternating rounds; base = {trees['base']}")
    print("peer CPU us/line: CPU time of the peer process per line (user + system), the load-proof figure")
    print(
        f"{'':34s} {'tree':>5s} {'lines/s':>9s} {'us/line':>8s} {'/ echo':>7s} {'this/base':>9s} {'peer CPU us/line':>16s}"
    )
    for (name, tree), rate in rows.items():
        base = rows.get((name, "base"))
        versus = f"{rate / base:9.2f}" if tree == "this" and base else ""
        print(
            f"{name:34s} {tree:>5s} {rate:9.0f} {1e6 / rate:8.1f} {rate / limit:7.2f} {versus:>9s} "
            f"{1e6 * cpu[(name, tree)]:16.1f}"
        )
    print(f"load average at the end: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())

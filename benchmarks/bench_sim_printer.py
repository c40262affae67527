"""The simulated printer's hot path, side by side: this tree's simulator against another tree's, in one run.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_sim_printer.py --base /tmp/base [--lines 2000] [--rounds 3]

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
    args = parser.parse_args()
    trees = {"base": args.base.resolve(), "this": HERE}
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

"""Marlin driver throughput over a pseudo-terminal, beside the pty's own round-trip limit.

Run: .venv/bin/python benchmarks/bench_marlin.py [--lines 3000]

Rows, all measured in this run over the same kind of pty, one line in flight:
  echo limit       a bare host loop (pyserial write, read to "ok\\n") against a bare peer that
                   answers every line with "ok" at once: the round trip of the pty itself.
  driver vs echo   MarlinDriver.send_lines against the same bare peer: the driver's own cost.
  bare vs sim      the bare host loop against the simulated printer: the simulator's cost.
  driver vs sim    MarlinDriver.send_lines against the simulated printer (virtual time).
  sim core only    the simulator's firmware model with no I/O at all (MarlinCore in-process).
The target: driver vs sim >= 80 % of the echo limit.

`--against REV` adds, in the same run, the driver rows of git revision REV (its `neatskin` exported
to a temporary folder and measured in a subprocess against the same peers), and the driver through
pyserial's read/write API instead of the raw descriptor (the transport's two channels).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import serial

REPO = Path(__file__).resolve().parent.parent
TREE = Path(os.environ.get("NEATSKIN_BENCH_TREE", REPO))  # the neatskin whose driver is measured
sys.path.insert(0, str(TREE))

from neatskin.gcode.parse import checksum  # noqa: E402
from neatskin.gcode.profile import load_printer_profile  # noqa: E402
from neatskin.marlin.driver import DriverConfig, MarlinDriver  # noqa: E402
from neatskin.sim.firmware import MarlinCore  # noqa: E402
from neatskin.sim.printer import SimulatedPrinter  # noqa: E402
from neatskin.sim.pty import open_pty, read_available, write_all  # noqa: E402

CONFIG = DriverConfig(boot_timeout_s=0.05, motion_time_scale=0.0)


class EchoPeer:
    """Answers every complete line with `ok` at once; nothing else."""

    def __init__(self) -> None:
        self.pty = open_pty()
        self.path = self.pty.path
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                pending += read_available(self.pty.master_fd, 0.05)
            except OSError:
                return
            count = pending.count(b"\n")
            if count:
                pending = pending[pending.rfind(b"\n") + 1 :]
                write_all(self.pty.master_fd, b"ok\n" * count)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        self.pty.close()


ECHO_SCRIPT = """
import sys
from neatskin.sim.pty import open_pty, read_available, write_all
pty = open_pty()
print(pty.path, flush=True)
pending = b""
while True:
    pending += read_available(pty.master_fd, 0.5)
    count = pending.count(b"\\n")
    if count:
        pending = pending[pending.rfind(b"\\n") + 1:]
        write_all(pty.master_fd, b"ok\\n" * count)
"""


class PeerProcess:
    """A peer in its own process (its own GIL), as a real printer is: the echo peer or `neatskin sim printer`."""

    def __init__(self, kind: str) -> None:
        import subprocess

        if kind == "echo":
            argv = [sys.executable, "-c", ECHO_SCRIPT]
        else:
            argv = [sys.executable, "-m", "neatskin", "sim", "printer", "--time", "virtual"]
            if kind == "sim-advanced-ok":
                argv.append("--advanced-ok")
        env = {**os.environ, "PYTHONPATH": str(REPO)}  # the same peer whichever driver is measured
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO, env=env
        )
        self.path = self.proc.stdout.readline().strip()

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=5)


def framed_lines(n: int) -> list[bytes]:
    out = []
    for i in range(n):
        body = f"N{i + 1} G1 X{10 + i % 100} Y{20 + i % 50} F6000"
        out.append(f"{body}*{checksum(body)}\n".encode())
    return out


def bare_host(path: str, lines: list[bytes], preamble: list[bytes] = ()) -> float:
    """Lines per second of the simplest possible host loop (no parsing, no recovery)."""
    port = serial.Serial(path, 115200, timeout=1.0)
    try:
        port.reset_input_buffer()
        for line in preamble:
            port.write(line)
            _read_ok(port)
        start = time.perf_counter()
        for line in lines:
            port.write(line)
            _read_ok(port)
        return len(lines) / (time.perf_counter() - start)
    finally:
        port.close()


def _read_ok(port) -> None:
    got = b""
    while not got.endswith(b"ok\n"):
        chunk = port.read(port.in_waiting or 1)
        if not chunk:
            raise RuntimeError("no ok within 1 s")
        got += chunk


HOST_CPU_US: list[float] = []  # host CPU (this process, all threads) per line of each driver_rate call


def driver_rate(port, commands: list[str], warmup: list[str], config: DriverConfig = CONFIG) -> float:
    driver = MarlinDriver(port, config=config)
    try:
        driver.connect()
        for command in warmup:
            driver.send(command)
        start, cpu = time.perf_counter(), time.process_time()
        driver.send_lines(commands)
        wall = time.perf_counter() - start
        HOST_CPU_US.append(1e6 * (time.process_time() - cpu) / len(commands))
        return len(commands) / wall
    finally:
        driver.close()


def core_rate(profile, commands: list[str]) -> float:
    core = MarlinCore(profile)
    core.receive(b"G28\n")
    core.step()
    core.take_output()
    lines = [f"N{i + 1} {c}*{checksum(f'N{i + 1} {c}')}\n".encode() for i, c in enumerate(commands)]
    core.receive(b"N0 M110 N0*125\n")
    core.step()
    start = time.perf_counter()
    for line in lines:
        core.receive(line)
        core.step()
        core.take_output()
    return len(lines) / (time.perf_counter() - start)


def step_costs(profile) -> dict[str, float]:
    """Microseconds per call of each step the driver takes per line (in isolation, this process)."""
    import timeit

    from neatskin.gcode.parse import parse_line
    from neatskin.marlin.deadlines import MotionTracker
    from neatskin.marlin.replies import classify, frame

    tracker = MotionTracker(profile)
    tracker.line_time_s("G28")
    parsed = parse_line("G1 X10 Y20 F6000")
    peer = EchoPeer()
    port = serial.Serial(peer.path, 115200, timeout=1.0)
    line = framed_lines(1)[0]
    cond = threading.Condition(threading.RLock())

    def round_trip() -> None:
        port.write(line)
        _read_ok(port)

    steps = {
        "classify a reply line": lambda: classify("ok"),
        "frame N<n> <cmd>*<cs>": lambda: frame("G1 X10 Y20 F6000", 1234),
        "deadline from the motion model": lambda: tracker.line_time_s(parsed),
        "parse a G-code line (send_lines, once)": lambda: parse_line("G1 X10 Y20 F6000"),
        "Condition (RLock) acquire + notify_all": lambda: (cond.acquire(), cond.notify_all(), cond.release()),
        "pyserial write + read ok (bare round trip)": round_trip,
    }
    try:
        return {name: timeit.timeit(fn, number=2000) / 2000 * 1e6 for name, fn in steps.items()}
    finally:
        port.close()
        peer.stop()


class ApiSerial(serial.Serial):
    """A POSIX serial port the transport does not recognise: it goes through pyserial's read/write."""


def driver_rows(commands: list[str], repeats: int) -> dict[str, float]:
    """The driver against the echo peer and the simulated printer, each in its own process (lines/s)."""

    cpu: dict[str, float] = {}

    def run(kind: str, warmup: list[str], port_type: type = serial.Serial, name: str = "") -> float:
        def once() -> float:
            peer = PeerProcess(kind)
            try:
                port = port_type()
                port.port = peer.path
                rate = driver_rate(port, commands, warmup)
                cpu[name] = min(cpu.get(name, float("inf")), HOST_CPU_US[-1])
                return rate
            finally:
                peer.stop()

        return max(once() for _ in range(repeats))

    rows = {
        "driver vs echo peer": run("echo", [], name="driver vs echo peer"),
        "driver vs sim printer": run("sim", ["G28"], name="driver vs sim printer"),
        "driver vs sim printer, pyserial API channel": run("sim", ["G28"], ApiSerial),
    }
    # the driver's own CPU per line (its process, reader thread included): the figure machine load does not move
    rows.update({f"{name}: host CPU us/line (lower is better)": us for name, us in cpu.items() if name})
    return rows


def against(rev: str, commands: list[str], repeats: int) -> dict[str, float]:
    """driver_rows of git revision rev, measured in a subprocess on its exported `neatskin`."""
    import json
    import subprocess
    import tarfile
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / "tree.tar"
        subprocess.run(["git", "archive", "-o", str(archive), rev, "neatskin"], cwd=REPO, check=True)
        with tarfile.open(archive) as tar:
            tar.extractall(tmp, filter="data")
        env = {**os.environ, "NEATSKIN_BENCH_TREE": tmp}
        argv = [sys.executable, __file__, "--driver-rows-json", "--lines", str(len(commands))]
        out = subprocess.run(argv + ["--repeats", str(repeats)], env=env, capture_output=True, text=True, check=True)
        return {name: float(rate) for name, rate in json.loads(out.stdout).items()}


def rates_limit(rows: dict[str, float]) -> float:
    return rows["echo limit (bare host, bare peer) | peer in its own process"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs per row")
    parser.add_argument("--against", default=None, metavar="REV", help="also measure the driver of git revision REV")
    parser.add_argument("--driver-rows-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    profile = load_printer_profile(REPO / "protocols" / "printers" / "paper.toml")
    commands = [f"G1 X{10 + i % 100} Y{20 + i % 50} F6000" for i in range(args.lines)]
    if args.driver_rows_json:
        import json

        print(json.dumps(driver_rows(commands, args.repeats)))
        return 0
    if args.against:  # alternate the two trees, so load drifts hit both alike
        import statistics

        runs_now: list[dict[str, float]] = []
        runs_before: list[dict[str, float]] = []
        for _ in range(args.repeats):
            runs_before.append(against(args.against, commands, 1))
            runs_now.append(driver_rows(commands, 1))
        print(f"{args.lines} lines, one in flight, peers in their own process, {args.repeats} alternating runs")
        print(f"{'lines/s (or us): median (min-max)':62s} {args.against[:12]:>20s} {'this tree':>20s} {'ratio':>6s}")
        for name in runs_now[0]:
            if name not in runs_before[0]:
                continue
            now = [run[name] for run in runs_now]
            before = [run[name] for run in runs_before]
            ratio = statistics.median(now) / statistics.median(before)
            cells = [f"{statistics.median(v):6.1f} ({min(v):.1f}-{max(v):.1f})" for v in (before, now)]
            print(f"{name:62s} {cells[0]:>20s} {cells[1]:>20s} {ratio:6.2f}")
        print(f"load average: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores")
        print()
    rows: dict[str, float] = {}

    def best(fn) -> float:
        return max(fn() for _ in range(args.repeats))

    def with_peer(kind: str, fn, process: bool):
        def run() -> float:
            if process:
                peer = PeerProcess(kind)
            else:
                peer = EchoPeer() if kind == "echo" else SimulatedPrinter(profile)
                if kind != "echo":
                    peer.path = peer.start_pty()
            try:
                return fn(peer.path)
            finally:
                peer.stop()

        return run

    lines = framed_lines(args.lines)
    hello = [b"N0 M110 N0*125\n", b"G28\n"]
    for process in (True, False):
        where = "peer in its own process" if process else "peer in this process (shares the GIL)"
        rows[f"echo limit (bare host, bare peer) | {where}"] = best(
            with_peer("echo", lambda p: bare_host(p, lines), process)
        )
        rows[f"driver vs echo peer | {where}"] = best(
            with_peer("echo", lambda p: driver_rate(serial.serial_for_url(p, do_not_open=True), commands, []), process)
        )
        rows[f"bare host vs sim printer | {where}"] = best(
            with_peer("sim", lambda p: bare_host(p, lines, hello), process)
        )
        rows[f"driver vs sim printer | {where}"] = best(
            with_peer(
                "sim", lambda p: driver_rate(serial.serial_for_url(p, do_not_open=True), commands, ["G28"]), process
            )
        )
    pipelined = DriverConfig(boot_timeout_s=0.05, motion_time_scale=0.0, max_in_flight=4)
    rows["driver vs sim, ok N P B, up to 4 in flight | peer in its own process"] = best(
        with_peer(
            "sim-advanced-ok",
            lambda p: driver_rate(serial.serial_for_url(p, do_not_open=True), commands, ["G28"], pipelined),
            True,
        )
    )
    rows["sim core only (no I/O)"] = best(lambda: core_rate(profile, commands))
    print(f"{args.lines} lines, one in flight, best of {args.repeats}; ratio = rate / echo limit of the same group")
    print(f"{'':62s} {'lines/s':>9s} {'us/line':>8s} {'ratio':>6s}")
    for name, rate in rows.items():
        group = name.split(" | ")[-1]
        limit = rows.get(f"echo limit (bare host, bare peer) | {group}", rates_limit(rows))
        print(f"{name:62s} {rate:9.0f} {1e6 / rate:8.1f} {rate / limit:6.2f}")
    print()
    print("where a line's time goes (us per call, measured alone in this process):")
    for name, us in step_costs(profile).items():
        print(f"  {name:48s} {us:7.2f}")
    print(f"  {'sim firmware model per line (MarlinCore)':48s} {1e6 / rows['sim core only (no I/O)']:7.2f}")
    group = "peer in its own process"
    print(
        f"driver / bare host against the same peer: echo peer "
        f"{rows[f'driver vs echo peer | {group}'] / rows[f'echo limit (bare host, bare peer) | {group}']:.2f}, "
        f"sim printer {rows[f'driver vs sim printer | {group}'] / rows[f'bare host vs sim printer | {group}']:.2f}"
    )
    limit = rows["echo limit (bare host, bare peer) | peer in its own process"]
    ratio = rows["driver vs sim printer | peer in its own process"] / limit
    print(
        f"target: driver vs sim printer >= 0.80 of the echo limit: {'met' if ratio >= 0.8 else 'NOT met'} ({ratio:.2f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

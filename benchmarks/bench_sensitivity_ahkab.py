"""Benchmark: the paper's sensitivity map (each of 12 channels +50 % in turn, 28 pairs) against Ahkab, side by side.

    python benchmarks/bench_sensitivity_ahkab.py [--rounds 9] [--against DIR]

Ahkab (a pure-Python SPICE-like simulator, `pip install ahkab`, the `bench` extra) computes the map as a
circuit simulator would: for each of the 13 states (unchanged, then each channel at +50 %) and each of the
28 pairs, an operating-point analysis of the network with 1 A driven into one electrode and the other
grounded, R_eq = V. Beside it, two neatskin paths on the same layout:

    rank-one   skin.maps.paper_sensitivity: Sherman-Morrison updates of one grounded inverse (this branch)
    full solve the 13 states through network.equivalent_resistance, then differences

and, with --against DIR (a checkout of another commit, e.g. `git worktree add --detach DIR 513ce57`), that
checkout's skin.maps.paper_sensitivity, timed in a worker process that imports the toolkit from DIR (the same
Python, BLAS pinned the same way), in the same alternating rounds.

Each round times every path once, alternating (Ahkab's one map against the mean of enough neatskin maps to
fill ~0.2 s, the clock read once per doubling batch of maps, not once a map), in process CPU time; the table gives the median over rounds of the per-round ratio, with the
range, and the largest difference between the maps. BLAS threads are pinned to 1. Ahkab 0.18 (2015) needs
three shims on current SciPy and NumPy (tests/ahkab_load.py, applied only where Ahkab is used): its window imports moved to scipy.signal.windows,
and its per-element report (which calls float() on a 1x1 array, and which the map does not read) is skipped.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from neatskin.layout import load_layout  # noqa: E402
from neatskin.skin.maps import paper_sensitivity  # noqa: E402
from neatskin.skin.network import equivalent_resistance  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def _import_ahkab():
    sys.path.insert(0, str(REPO / "tests"))  # the shims Ahkab needs live beside the tests that use it too
    from ahkab_load import import_ahkab

    return import_ahkab()


def ahkab_map(ahkab, layout, increase: float = 0.5) -> np.ndarray:
    """(channels, pairs) dR_eq from 13 x 28 Ahkab operating points."""
    from ahkab import circuit

    r0 = layout.channel_resistance_ohm
    ends = layout.channel_ends.tolist()
    elec = layout.electrode_junctions.tolist()
    op = ahkab.new_op(outfile=None, verbose=0)
    r_eq = np.empty((layout.n_channels + 1, len(layout.pairs)))
    for state in range(layout.n_channels + 1):
        resistance = r0.copy()
        if state:
            resistance[state - 1] *= 1.0 + increase
        for k, (ia, ib) in enumerate(layout.pair_electrode_index.tolist()):
            a, b = elec[ia], elec[ib]
            c = circuit.Circuit(f"s{state}p{k}")
            node = {j: (c.gnd if j == b else f"n{j}") for j in range(layout.n_junctions)}
            for i, (u, v) in enumerate(ends):
                c.add_resistor(f"R{i}", node[u], node[v], float(resistance[i]))
            c.add_isource("I1", c.gnd, node[a], dc_value=1.0)  # 1 A from ground (b) into a
            r_eq[state, k] = float(ahkab.run(c, op)["op"][f"VN{a}"][0][0])
    return r_eq[1:] - r_eq[0]


def full_solve_map(layout, increase: float = 0.5) -> np.ndarray:
    resistance = np.tile(layout.channel_resistance_ohm, (layout.n_channels + 1, 1))
    resistance[np.arange(1, layout.n_channels + 1), np.arange(layout.n_channels)] *= 1.0 + increase
    r_eq = equivalent_resistance(layout, 1.0 / resistance)
    return r_eq[1:] - r_eq[0]


def _cpu_per_call(fn, budget_s: float = 0.2) -> float:
    """CPU seconds a call over at least budget_s, the clock read once per batch of calls (batches doubling): reading
    it once per call counted a process_time() (a system call, 0.5-1.4 us here) in every map of a few microseconds."""
    fn()
    batch, calls, started = 1, 0, time.process_time()
    while True:
        for _ in range(batch):
            fn()
        calls += batch
        spent = time.process_time() - started
        if spent >= budget_s:
            return spent / calls
        batch *= 2


class _Against:
    """paper_sensitivity of another checkout, in a worker process that imports the toolkit from there."""

    def __init__(self, checkout: Path) -> None:
        self.name = checkout.name[:11]  # the table's path column
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--worker"],
            cwd=checkout,
            env={**os.environ, "PYTHONPATH": str(checkout)},
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.map = np.array(json.loads(self._ask("map")))

    def _ask(self, command: str) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline()

    def cpu_per_call(self) -> float:
        return float(self._ask("time"))

    def close(self) -> None:
        self._ask("quit")
        self.proc.wait(timeout=30)


def _worker() -> None:
    """The --against side: answers 'map' (the map as JSON), 'time' (CPU s a map), 'quit', one per line."""
    layout = load_layout(Path.cwd() / "protocols" / "skins" / "paper.toml")
    for line in sys.stdin:
        command = line.strip()
        if command == "map":
            print(json.dumps(paper_sensitivity(layout).delta_ohm.tolist()), flush=True)
        elif command == "time":
            print(repr(_cpu_per_call(lambda: paper_sensitivity(layout).delta_ohm)), flush=True)
        else:
            print("bye", flush=True)
            return


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--against", type=Path, help="a checkout of another commit: time its paper_sensitivity too")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        _worker()
        return
    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    ahkab = _import_ahkab()
    reference = ahkab_map(ahkab, layout)
    ours = {"rank-one": lambda: paper_sensitivity(layout).delta_ohm, "full solve": lambda: full_solve_map(layout)}
    maps = {"rank-one": ours["rank-one"](), "full solve": ours["full solve"]()}
    timers = {name: (lambda fn=fn: _cpu_per_call(fn)) for name, fn in ours.items()}
    against = _Against(args.against.resolve()) if args.against else None
    if against is not None:
        timers[against.name] = against.cpu_per_call
        maps[against.name] = against.map
    ratios: dict[str, list[float]] = {name: [] for name in timers}
    per_call: dict[str, list[float]] = {name: [] for name in timers}
    ahkab_s = []
    load_before = os.getloadavg()
    for _ in range(args.rounds):
        started = time.process_time()
        ahkab_map(ahkab, layout)
        ahkab_s.append(time.process_time() - started)
        for name, timer in timers.items():
            per_call[name].append(timer())
            ratios[name].append(ahkab_s[-1] / per_call[name][-1])
    load_after = os.getloadavg()
    if against is not None:
        against.close()
    print(f"sensitivity map (12 channels x 28 pairs), paper skin, {args.rounds} alternating rounds, CPU time, 1 thread")
    print(f"load average (1 min) before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    print(f"Ahkab: median {np.median(ahkab_s) * 1e3:.1f} ms a map")
    if against is not None:
        print(f"{against.name}: paper_sensitivity of the checkout {args.against.resolve()}, in a worker process")
    print(f"{'path':<11} {'us a map':>9} {'x Ahkab (median)':>17} {'range':>19} {'max |diff| ohm':>15}")
    for name in timers:
        diff = float(np.max(np.abs(maps[name] - reference)))
        lo, hi = min(ratios[name]), max(ratios[name])
        print(
            f"{name:<11} {np.median(per_call[name]) * 1e6:>9.1f} {np.median(ratios[name]):>17,.0f} "
            f"{lo:>9,.0f}-{hi:<9,.0f} {diff:>15.2e}"
        )


if __name__ == "__main__":
    main()

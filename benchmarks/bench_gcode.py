"""Benchmark: generate and validate the paper campaign (100 positions x 28 presses) and compare the wall
time with the printer time the program will take.

    .venv/bin/python benchmarks/bench_gcode.py [--repeats 5] [--against DIR [--plan-presses 28000]]

Prints one table (best of --repeats runs per stage) and the ratio estimated printer time / generation time.
`--against DIR` (a checkout of another commit, e.g. `git worktree add /tmp/base 80806b2`) adds, in the
same run, build_plan's motion-time estimate (gcode.motion.phase_durations_s on the paper campaign: every
phase of every press) timed in a subprocess of each tree, alternating, with a check that both trees give
the same durations to the bit. With `--plan-presses N` (a multiple of 28) it also builds the plan of the paper
protocol scaled to N presses in each tree (fresh processes, alternating): load_protocol and build_plan time,
the memory build_plan holds and peaks at (tracemalloc), the time to make every press block once (what the
runner does, one block per press), and a sha256 of every command line, which must agree between the trees.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from neatskin.gcode.bounds import check_moves
from neatskin.gcode.motion import estimate_program_time
from neatskin.gcode.parse import parse_program
from neatskin.gcode.positions import generate_positions
from neatskin.gcode.profile import load_printer_profile
from neatskin.gcode.program import build_program
from neatskin.gcode.spec import load_gcode_spec
from neatskin.layout import load_layout

PROTOCOL = Path(__file__).resolve().parent.parent / "protocols" / "paper.toml"
HERE = Path(__file__).resolve().parent.parent
PHASES = """
import hashlib, json, time
from neatskin.gcode.motion import phase_durations_s
from neatskin.gcode.spec import build_from_spec
from neatskin.rig.protocol import load_protocol
protocol = load_protocol("protocols/paper.toml")
program, _, _ = build_from_spec(protocol.press, hold_in_gcode=False, layout=protocol.layout, profile=protocol.printer)
start = time.perf_counter()
durations = phase_durations_s(program, protocol.printer)
wall = time.perf_counter() - start
print(json.dumps({"s": wall, "digest": hashlib.sha256(durations.tobytes()).hexdigest(), "shape": durations.shape}))
"""


PLAN = """
import hashlib, json, sys, time, tracemalloc
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan
t0, c0 = time.perf_counter(), time.process_time()
protocol = load_protocol(sys.argv[1])
load_s, load_cpu = time.perf_counter() - t0, time.process_time() - c0
t0, c0 = time.perf_counter(), time.process_time()
plan = build_plan(protocol)
build_s, build_cpu = time.perf_counter() - t0, time.process_time() - c0
del plan
tracemalloc.start()
plan = build_plan(protocol)
held, peak = tracemalloc.get_traced_memory()
tracemalloc.stop()
t0 = time.perf_counter()
digest = hashlib.sha256()
for block in plan.program.presses:
    for phase in block.phases:
        digest.update("\\n".join(phase.lines).encode())
blocks_s = time.perf_counter() - t0
print(json.dumps({"presses": plan.n_presses, "load_s": load_s, "load_cpu_s": load_cpu, "build_s": build_s,
                  "build_cpu_s": build_cpu, "held_mb": held / 2**20, "peak_mb": peak / 2**20, "blocks_s": blocks_s,
                  "digest": digest.hexdigest()}))
"""


def plan_against(base: Path, presses: int, rounds: int) -> None:
    """The plan of a paper protocol scaled to `presses`, built in this tree and in base (fresh processes,
    alternating): time, tracemalloc memory, one pass over every block, and the G-code's digest."""
    import json
    import os
    import shutil
    import statistics
    import subprocess
    import sys
    import tempfile

    if presses % 28:
        raise SystemExit(f"--plan-presses must be a multiple of 28 (the paper's repeats), got {presses}")
    work = Path(tempfile.mkdtemp(prefix="bench-gcode-plan-"))
    try:
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(HERE / "protocols" / sub, work / sub)
        protocol = work / f"paper-{presses}.toml"
        protocol.write_text(PROTOCOL.read_text().replace("count = 100", f"count = {presses // 28}"))
        runs: dict[str, list[dict]] = {"base": [], "this": []}
        for _ in range(rounds):
            for name, tree in (("base", base.resolve()), ("this", HERE)):
                out = subprocess.run(
                    [sys.executable, "-c", PLAN, str(protocol)],
                    cwd=tree,  # `python -c` puts the working directory first on sys.path, before PYTHONPATH
                    env={**os.environ, "PYTHONPATH": str(tree)},
                    capture_output=True,
                    text=True,
                    check=True,
                )
                runs[name].append(json.loads(out.stdout))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    keys = ("load_s", "load_cpu_s", "build_s", "build_cpu_s", "held_mb", "peak_mb", "blocks_s")
    print(f"plan of the paper protocol scaled to {presses:,} presses, median of {rounds} rounds per tree:")
    print("| tree | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    median = {n: {k: statistics.median(r[k] for r in rs) for k in keys} for n, rs in runs.items()}
    for name in ("base", "this"):
        print(f"| {name} | " + " | ".join(f"{median[name][k]:.2f}" for k in keys) + " |")
    print("| this/base | " + " | ".join(f"{median['this'][k] / median['base'][k]:.2f}" for k in keys) + " |")
    digests = {r["digest"] for rs in runs.values() for r in rs}
    print(
        f"every command line identical in both trees (sha256): {'yes' if len(digests) == 1 else 'NO'}; "
        f"load {os.getloadavg()[0]:.1f}"
    )
    print()


def phase_durations_against(base: Path, rounds: int) -> None:
    """build_plan's estimate in this tree and in base, alternating subprocesses (each its own start-up)."""
    import json
    import os
    import statistics
    import subprocess
    import sys

    times: dict[str, list[float]] = {"base": [], "this": []}
    digests: dict[str, set[str]] = {"base": set(), "this": set()}
    for _ in range(rounds):
        for name, tree in (("base", base.resolve()), ("this", HERE)):
            out = subprocess.run(
                [sys.executable, "-c", PHASES],
                cwd=tree,
                env={**os.environ, "PYTHONPATH": str(tree)},
                capture_output=True,
                text=True,
                check=True,
            )
            result = json.loads(out.stdout)
            times[name].append(result["s"])
            digests[name].add(result["digest"])
    cells = {k: f"{1e3 * statistics.median(v):7.1f} ({1e3 * min(v):.1f}-{1e3 * max(v):.1f})" for k, v in times.items()}
    ratio = statistics.median(times["this"]) / statistics.median(times["base"])
    same = digests["this"] == digests["base"] and len(digests["this"]) == 1
    print(f"phase_durations_s (build_plan's estimate, paper campaign), ms median (min-max) of {rounds} rounds:")
    print(f"  base {cells['base']}   this tree {cells['this']}   this/base {ratio:.2f}")
    print(f"  durations identical to the bit: {'yes' if same else 'NO'}; load {os.getloadavg()[0]:.1f}")
    print()


def best_of(repeats: int, fn):
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--against", type=Path, default=None, help="a checkout of the commit to compare with")
    parser.add_argument(
        "--plan-presses", type=int, default=None, help="with --against: also the plan of this many presses (x28)"
    )
    args = parser.parse_args()
    if args.against is not None:
        phase_durations_against(args.against, args.repeats)
        if args.plan_presses:
            plan_against(args.against, args.plan_presses, args.repeats)

    spec = load_gcode_spec(PROTOCOL)
    layout = load_layout(spec.layout_path)
    profile = load_printer_profile(spec.printer_path)
    stages = []
    t, positions = best_of(args.repeats, lambda: generate_positions(layout, spec.positions))
    stages.append(("positions (100, paper strategy)", t))
    t, program = best_of(
        args.repeats,
        lambda: build_program(
            layout, positions, spec.press, profile, name=spec.name, seed=spec.seed, hold_in_gcode=True
        ),
    )
    stages.append(("program: bounds + 2,800 presses' numbers", t))
    t, text = best_of(args.repeats, program.text)
    stages.append(("emit text (each block made as it is read)", t))
    generation = sum(s for _, s in stages)
    t, lines = best_of(args.repeats, lambda: parse_program(text))
    stages.append(("validate: parse every line", t))
    t, problems = best_of(args.repeats, lambda: check_moves(profile, lines))
    stages.append(("validate: bounds of every move", t))
    assert not problems
    t, estimate = best_of(args.repeats, lambda: estimate_program_time(lines, profile))
    stages.append(("validate: motion-time estimate", t))
    total = sum(s for _, s in stages)

    ordered_spec = replace(spec.press, travel_ordering=True)
    t_ord, ordered = best_of(
        args.repeats,
        lambda: build_program(
            layout, positions, ordered_spec, profile, name=spec.name, seed=spec.seed, hold_in_gcode=True
        ),
    )
    ordered_estimate = estimate_program_time(ordered.command_lines(), profile)

    print(
        f"paper campaign: {len(program.positions)} positions x {spec.press.repeats} repeats = "
        f"{len(program.presses)} presses, {len(text.splitlines())} lines, {len(text) / 1e6:.2f} MB"
    )
    print(f"{'stage':<40} {'wall time (best of ' + str(args.repeats) + ')':>26}")
    for name, seconds in stages:
        print(f"{name:<40} {seconds * 1e3:>23.1f} ms")
    print(f"{'generate (positions + program + text)':<40} {generation * 1e3:>23.1f} ms")
    print(f"{'generate + validate':<40} {total * 1e3:>23.1f} ms")
    print()
    print(
        f"estimated printer time: {estimate.total_s:,.0f} s = {estimate.total_s / 3600:.2f} h "
        f"(motion {estimate.motion_s:,.0f} s, G4 holds {estimate.dwell_s:,.0f} s, homing {estimate.homing_s:.0f} s)"
    )
    print(f"ratio printer time / (generate + validate): {estimate.total_s / total:,.0f} x")
    print(f"ratio printer time / generate alone:        {estimate.total_s / generation:,.0f} x")
    print()
    saved = ordered.route_unordered_mm - ordered.route_mm
    print(
        f"travel ordering (nearest neighbour + 2-opt, {t_ord * 1e3:.1f} ms to build): xy route between positions "
        f"{ordered.route_unordered_mm:.0f} mm -> {ordered.route_mm:.0f} mm ({100 * saved / ordered.route_unordered_mm:.0f} % "
        f"shorter); printer time {estimate.total_s:,.0f} s -> {ordered_estimate.total_s:,.0f} s "
        f"({estimate.total_s - ordered_estimate.total_s:.1f} s saved)"
    )


if __name__ == "__main__":
    main()

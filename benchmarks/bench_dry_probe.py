"""The dry run's per-press skin and DAQ work: SimulatedRecorder.end() per press, this checkout against another, side by side.

    python benchmarks/bench_dry_probe.py [--against DIR] [--presses 200] [--repeats 5] [--protocol P]
    python benchmarks/bench_dry_probe.py --quadrature-only      # only the quadrature rows (section 2)

1. recorder.end() per press. A dry run of the protocol (default protocols/paper.toml, its "paper-like" scene)
   runs --presses presses through the real rig's path (G-code over a pty, driver, recorder, writer) once,
   and every press's recorder inputs are captured: the press id, the sweeps, the printer clock at begin()
   and at each mark, and the printer's moves from begin() on. Each checkout then builds its own dry rig from
   the protocol in a child process (PYTHONPATH = that checkout) and replays the captured presses through its
   `SimulatedRecorder.end()` --repeats times; the table gives the best CPU time per press (thread time, so
   the other processes on a shared machine count less) and compares every record's arrays with this
   checkout's, bit for bit (or the largest relative difference). Make the base checkout with
   `git worktree add /tmp/base DIR-COMMIT`. The children alternate, so a change in load hits both.
2. Quadrature rows, old way against new way in one process: R / R0 and the pinched length share as two
   quadratures against one pass (`factor_and_length_fraction`), and the quadrature over presses that do not
   touch the skin (integrated, then overwritten with 1) against skipped. Each pair is checked bit for bit.

Runs on one core (BLAS threads pinned to 1).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import pickle  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
PROBE_RADIUS_MM = 2.75


def best_time_s(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


# ---- 1. recorder.end() per press, replayed in each checkout -------------------------------------------------


def capture(protocol_path: str, presses: int, out: str) -> None:
    """Child: a dry run of `presses` presses, saving every press's recorder inputs to `out` (pickle)."""
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign
    from neatskin.sim import recorder as recorder_module

    captured = []
    original_end = recorder_module.SimulatedRecorder.end

    def end(self):
        segments = [tuple(s) for s in self.probe.segments_from(self._t0)]
        captured.append((self._press, self._n_sweeps, self._t0, dict(self._marks), segments))
        return original_end(self)

    recorder_module.SimulatedRecorder.end = end  # type: ignore[method-assign]
    with tempfile.TemporaryDirectory() as folder:
        run_campaign(load_protocol(protocol_path), Path(folder) / "c", progress=False, report=False, limit=presses)
    with open(out, "wb") as f:
        pickle.dump(captured, f)


def _rig_plan(build_dry_rig, plan):
    """What this checkout's build_dry_rig takes: the Plan (rig/plan.py), or the sweep alone (older checkouts)."""
    import inspect

    return plan if "plan" in inspect.signature(build_dry_rig).parameters else plan.sweep


def replay(protocol_path: str, captured_path: str, repeats: int, out: str) -> None:
    """Child: this checkout's dry rig, the captured presses through its recorder; best CPU time and the records."""
    try:
        from neatskin.rig.dryrig import build_dry_rig
    except ImportError:  # an older checkout: the dry rig's builder in rig/assembly.py
        from neatskin.rig.assembly import build_dry_rig
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import build_plan
    from neatskin.sim.motion import Segment

    protocol = load_protocol(protocol_path)
    plan = build_plan(protocol)
    with open(captured_path, "rb") as f:
        captured = pickle.load(f)
    presses = [(p, n, t0, marks, [Segment(*s) for s in segs]) for p, n, t0, marks, segs in captured]
    rig = build_dry_rig(protocol, _rig_plan(build_dry_rig, plan), skin_worker=False)  # the inline recorder
    try:
        recorder = rig.recorder
        now = {"t": 0.0, "segments": []}
        recorder.clock = lambda: now["t"]
        recorder.probe.segments_from = lambda t0_s: now["segments"]
        best, records = float("inf"), []
        for _ in range(repeats):
            records = []
            start = time.thread_time()
            for press_id, n_sweeps, t0, marks, segments in presses:
                now["t"], now["segments"] = t0, segments
                recorder.begin(press_id, n_sweeps)
                for name, t in marks.items():
                    now["t"] = t
                    recorder.mark(name)
                records.append(recorder.end())
            best = min(best, time.thread_time() - start)
    finally:
        rig.close()
    arrays = [
        {
            "resistance_ohm": r.estimates.resistance_ohm,
            "uncertainty_ohm": r.estimates.uncertainty_ohm,
            "flags": r.estimates.flags,
            "windows": r.estimates.windows,
            "fsr_v": r.fsr_v,
            "marks": np.array(sorted(r.marks.values())),
            "first_sample": np.array([r.first_sample, r.n_samples]),
        }
        for r in records
    ]
    with open(out, "wb") as f:
        pickle.dump({"ms_per_press": 1e3 * best / len(presses), "records": arrays}, f)


def _child(checkout: Path, *args: str) -> None:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    subprocess.run([sys.executable, str(Path(__file__).resolve()), *args], env=env, check=True)


def compare(this: list[dict], other: list[dict]) -> tuple[int, dict[str, float]]:
    """Records identical bit for bit, and the largest relative difference per field where they are not."""
    identical, worst = 0, {}
    for a, b in zip(this, other, strict=True):
        same = True
        for key, x in a.items():
            y = b[key]
            if x is None or y is None:
                same &= x is None and y is None
                continue
            if x.tobytes() == y.tobytes():
                continue
            same = False
            if x.dtype.kind == "f" and x.shape == y.shape:
                with np.errstate(divide="ignore", invalid="ignore"):
                    rel = float(np.nanmax(np.abs(x - y) / np.maximum(np.abs(y), 1e-300)))
            else:
                rel = float("inf")
            worst[key] = max(worst.get(key, 0.0), rel)
        identical += same
    return identical, worst


def recorder_section(protocol: Path, presses: int, repeats: int, against: Path | None) -> None:
    checkouts = {"this": REPO} | ({} if against is None else {"against": against.resolve()})
    with tempfile.TemporaryDirectory() as folder:
        captured = str(Path(folder) / "captured.pkl")
        _child(REPO, "--child-capture", str(protocol), str(presses), captured)
        results: dict[str, list[dict]] = {name: [] for name in checkouts}
        for round_ in range(2):  # alternate, so a change in load hits both
            for name, checkout in checkouts.items():
                out = str(Path(folder) / f"{name}-{round_}.pkl")
                _child(checkout, "--child-replay", str(protocol), captured, str(repeats), out)
                with open(out, "rb") as f:
                    results[name].append(pickle.load(f))
    load = os.getloadavg()
    print(
        f"\n1. SimulatedRecorder.end() per press, {protocol.name}, {presses} captured presses replayed, best CPU "
        f"time of {repeats} x 2 rounds (load average {load[0]:.2f})"
    )
    best = {name: min(r["ms_per_press"] for r in runs) for name, runs in results.items()}
    print(f"  {'checkout':<10} {'ms/press':>9} {'vs this':>7}  {'records equal to this one':<30}")
    for name, checkout in checkouts.items():
        ratio = best[name] / best["this"]
        identical, worst = compare(results["this"][0]["records"], results[name][0]["records"])
        diff = (
            "" if not worst else "  largest relative difference " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items())
        )
        print(f"  {name:<10} {best[name]:>9.3f} {ratio:>6.2f}x  {identical}/{presses} bit for bit{diff}   ({checkout})")


# ---- 2. quadrature rows -------------------------------------------------------------------------------------


def quadrature_section(states: int, repeats: int) -> None:
    from neatskin.layout import load_layout
    from neatskin.skin.deformation import (
        PinchParams,
        _factor_chunk,
        factor_and_length_fraction,
        pinched_length_fraction,
        resistance_factor,
    )
    from neatskin.tomlfile import resolve_path

    layout = load_layout(resolve_path("protocols/skins/paper.toml"))
    rng = np.random.default_rng(0)
    n = states
    x, y = rng.uniform(0, 15, n), rng.uniform(0, 15, n)
    depth = rng.uniform(0.05, 3.5, n)
    params = PinchParams()

    def two() -> tuple[np.ndarray, np.ndarray]:
        return (
            resistance_factor(layout, x, y, depth, PROBE_RADIUS_MM, params),
            pinched_length_fraction(layout, x, y, depth, PROBE_RADIUS_MM, params),
        )

    def one() -> tuple[np.ndarray, np.ndarray]:
        return factor_and_length_fraction(layout, x, y, depth, PROBE_RADIUS_MM, params)

    for a, b in zip(two(), one()):
        np.testing.assert_array_equal(a, b)

    zero = np.zeros(1)

    def untouched_integrated() -> np.ndarray:
        return _factor_chunk(layout, zero, zero, zero, np.full(1, PROBE_RADIUS_MM), params, None, False)

    def untouched_skipped() -> np.ndarray:
        return resistance_factor(layout, 0.0, 0.0, 0.0, PROBE_RADIUS_MM, params)

    np.testing.assert_array_equal(untouched_integrated(), untouched_skipped())

    rows = [
        (f"R/R0 + length share, {n} states", two, one),
        ("untouched press (baseline with dents)", untouched_integrated, untouched_skipped),
    ]
    print(f"\n2. quadrature, old way against new way (best of {repeats})")
    print(f"  {'work':42s} {'before ms':>10s} {'after ms':>10s} {'speed-up':>9s}")
    for name, before, after in rows:
        t_before, t_after = best_time_s(before, repeats), best_time_s(after, repeats)
        print(f"  {name:42s} {1e3 * t_before:10.3f} {1e3 * t_after:10.3f} {t_before / t_after:8.2f}x")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child-capture":
        capture(sys.argv[2], int(sys.argv[3]), sys.argv[4])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--child-replay":
        replay(sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, help="another checkout (e.g. the base commit) to replay side by side")
    parser.add_argument("--protocol", type=Path, default=REPO / "protocols" / "paper.toml")
    parser.add_argument("--presses", type=int, default=200, help="presses captured and replayed (default 200)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--states", type=int, default=60, help="distinct probe states in the quadrature rows")
    parser.add_argument("--quadrature-only", action="store_true")
    args = parser.parse_args()
    print(f"bench_dry_probe: one core, {os.cpu_count()} cores on the machine")
    if not args.quadrature_only:
        recorder_section(args.protocol.resolve(), args.presses, args.repeats, args.against)
    quadrature_section(args.states, max(args.repeats, 20))


if __name__ == "__main__":
    main()

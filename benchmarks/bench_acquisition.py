"""Acquisition benchmark: resistance error against processing time for RMS and lock-in at several live-window
lengths, the whole per-press pipeline's throughput as a multiple of real time (10 kHz x 3 channels), and the
dry run's per-press labelling (FSR label + row values), physical limit and start-up, side by side with another
checkout.

    .venv/bin/python benchmarks/bench_acquisition.py [--quick]
    .venv/bin/python benchmarks/bench_acquisition.py --labelling --against /tmp/base   # e.g. a worktree of HEAD~1

Everything runs on one core, side by side in one run. Targets: the pipeline >= 200 x real time; the labelling
(fsr_label + press_values) <= 0.3 ms per press. With --against, each checkout's numbers come from its own child
processes (PYTHONPATH = that checkout), alternating, best of the rounds, on the same inputs, and the outputs'
digests must agree.
"""

from __future__ import annotations

import os
import shutil

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from neatskin.acquisition.daq.base import DaqConfig  # noqa: E402
from neatskin.acquisition.demod import demodulate  # noqa: E402
from neatskin.acquisition.features import features_from_acquisition  # noqa: E402
from neatskin.acquisition.sequence import SweepTiming, build_sweep  # noqa: E402
from neatskin.acquisition.wiring import load_wiring  # noqa: E402
from neatskin.layout import load_layout  # noqa: E402
from neatskin.sim.daq import NoiseModel, SimulatedDAQ  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
R_TRUE = np.linspace(2_000.0, 8_000.0, 28)
# a noisier rig than the default, so the error is visible: 20 mV and 2 uA white, a 50 mV DC offset on V
BENCH_NOISE = NoiseModel(voltage_noise_v=0.02, current_noise_a=2e-6, voltage_offset_v=0.05)


def best_time(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def constant(t):
    return np.broadcast_to(R_TRUE, (len(t), 28))


def accuracy_table(wiring, n_sweeps: int, repeats: int) -> None:
    print(f"resistance error vs live window ({n_sweeps} sweeps x 28 pairs, noise: 20 mV, 2 uA, 50 mV offset)")
    print(
        f"{'method':>8} {'window':>6} {'live':>5} {'sweep ms':>8} {'rel RMSE ppm':>12} {'bias ppm':>9} "
        f"{'demod Msamp/s':>13} {'x real time':>11}"
    )
    for live in (20, 50, 100, 200, 500):
        sweep = build_sweep(wiring, SweepTiming(live_samples=live))
        daq = SimulatedDAQ(DaqConfig(), constant, noise=BENCH_NOISE)
        acq = daq.acquire(sweep, n_sweeps, rng=np.random.default_rng(live))
        for method, window in (("rms", 10), ("rms", 7), ("lockin", 10)):
            if method == "rms" and window == 7 and live != 100:
                continue
            est = demodulate(acq, sweep, method, window)
            rel = est.resistance_ohm / R_TRUE - 1
            seconds = best_time(
                lambda acq=acq, sweep=sweep, method=method, window=window: demodulate(acq, sweep, method, window),
                repeats,
            )
            rate = acq.n_samples / seconds
            print(
                f"{method:>8} {window:>6} {live:>5} {sweep.duration_s * 1e3:>8.1f} "
                f"{1e6 * np.sqrt(np.mean(rel**2)):>12.1f} {1e6 * rel.mean():>9.1f} "
                f"{rate * 3 / 1e6:>13.1f} {rate / 1e4:>11.0f}"
            )


def pipeline_table(wiring, presses: int, repeats: int) -> None:
    sweep = build_sweep(wiring)
    n_sweeps = 8  # 2.7 s per press: baseline, descent, hold, lift
    press_s = n_sweeps * sweep.duration_s
    change = np.where(np.arange(28) % 3 == 0, 0.2, 0.0)

    def skin(t):
        return R_TRUE * (1 + change * ((t % press_s > 0.8) & (t % press_s < 2.0))[:, None])

    def force(t):
        tp = t % press_s
        return 4.0 * np.minimum(np.clip((tp - 0.8) / 0.02, 0, 1), np.clip((2.0 - tp) / 0.02, 0, 1))

    rows = []
    for label, method in (("rms", "rms"), ("lockin", "lockin")):
        daq = SimulatedDAQ(DaqConfig(), skin, force)
        rng = np.random.default_rng(0)
        timings = {"simulate": 0.0, "demod+fsr+features": 0.0}
        errors = []
        for k in range(presses):
            t0 = time.perf_counter()
            acq = daq.acquire(sweep, n_sweeps, rng=rng, start_time_s=k * press_s)
            t1 = time.perf_counter()
            feats, det, _ = features_from_acquisition(acq, sweep, method, margin_s=0.01)
            t2 = time.perf_counter()
            timings["simulate"] += t1 - t0
            timings["demod+fsr+features"] += t2 - t1
            errors.append(feats.delta_r_ohm - R_TRUE * change)
            assert det.ok
        total = sum(timings.values())
        real = presses * press_s
        rows.append((f"waveforms + {label}", timings, total, real, np.sqrt(np.mean(np.square(errors)))))
    # features-only path: estimates straight from the noise model, no waveform, no FSR trace
    daq = SimulatedDAQ(DaqConfig(), skin, force)
    rng = np.random.default_rng(0)
    seconds = best_time(
        lambda: [daq.estimate_sweep(sweep, rng, k * press_s, "lockin", n_sweeps=n_sweeps) for k in range(presses)],
        repeats,
    )
    rows.append(("features-only lockin", {"estimate": seconds}, seconds, presses * press_s, float("nan")))
    print(
        f"\nwhole pipeline per press ({presses} presses x {n_sweeps} sweeps = {presses * press_s:.1f} s of signal, "
        "10 kHz x 3 channels)"
    )
    print(f"{'path':>22} {'ms/press':>9} {'x real time':>11} {'dR RMSE ohm':>11}  where the time goes")
    for label, timings, total, real, err in rows:
        split = ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in timings.items())
        print(f"{label:>22} {1e3 * total / presses:>9.2f} {real / total:>11.0f} {err:>11.3f}  {split}")


# ---- the dry run's per-press labelling, its physical limit and its start-up, per checkout ---------------------

LABELLING_CHILD = r"""
import hashlib, json, sys, time
import numpy as np
from neatskin.acquisition.estimates import PairEstimates
from neatskin.acquisition.fsr import FsrModel
from neatskin.acquisition.pressvalues import press_values
from neatskin.rig.pressrow import fsr_label

data = np.load(sys.argv[1])
repeats = int(sys.argv[2])
marks = dict(zip(("contact", "hold_start", "hold_end", "lifted"), data["marks"].tolist()))
labels = [f"p{k}" for k in range(data["r"].shape[2])]
model = FsrModel()
estimates = [PairEstimates(r, np.zeros_like(r), f, data["windows"]) for r, f in zip(data["r"], data["flags"])]
traces = list(data["fsr_v"])

def label_all():
    return [fsr_label(v, 1000.0, model, 0, marks, 10_000.0) for v in traces]

def values_all():
    return [press_values(e, marks, labels) for e in estimates]

t0 = time.perf_counter()
fsr_label(traces[0], 1000.0, model, 0, marks, 10_000.0)
first_ms = 1e3 * (time.perf_counter() - t0)
best = {"fsr_label": float("inf"), "press_values": float("inf")}
for _ in range(repeats):
    for name, fn in (("fsr_label", label_all), ("press_values", values_all)):
        t0 = time.perf_counter()
        out = fn()
        best[name] = min(best[name], (time.perf_counter() - t0) / len(traces))
        if name == "fsr_label":
            got_labels = out
        else:
            got_values = out
digest = hashlib.sha256()
for lab, val in zip(got_labels, got_values):
    digest.update(repr((lab.onset_s, lab.offset_s, lab.peak_n, lab.flags, val.flags)).encode())
    for a in (val.resistance_ohm, val.baseline_ohm, val.delta_r_ohm):
        digest.update(a.tobytes())
print(json.dumps({"first_ms": first_ms, **{k: 1e3 * v for k, v in best.items()}, "digest": digest.hexdigest()}))
"""

PHYSLIMIT_CHILD = r"""
import hashlib, inspect, json, sys, tempfile, time
from pathlib import Path
try:
    from neatskin.rig.dryrig import build_dry_rig
except ImportError:  # an older checkout: the dry rig's builder in rig/assembly.py
    from neatskin.rig.assembly import build_dry_rig
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan

protocol = load_protocol(Path(sys.argv[1]))
plan = build_plan(protocol)
# this checkout's build_dry_rig takes the Plan (rig/plan.py), an older one the sweep
rig = build_dry_rig(
    protocol, plan if "plan" in inspect.signature(build_dry_rig).parameters else plan.sweep, skin_worker=False
)
# this checkout's dry rig derives its physical limit itself (Rig.derived_files), an older one's runner did
if hasattr(rig, "derived_files"):
    write = rig.derived_files["physical_limit.parquet"]
else:
    from neatskin.rig.physlimit import write_physical_limit

    def write(folder):
        return write_physical_limit(folder, protocol, plan, rig)
best = float("inf")
try:
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(int(sys.argv[2])):
            t0 = time.perf_counter()
            path = write(Path(folder))
            best = min(best, time.perf_counter() - t0)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
finally:
    rig.close()
print(json.dumps({"physical_limit_s": best, "digest": digest}))
"""


def labelling_inputs(path: Path, presses: int) -> None:
    """Paper-like press records: 8.54 s FSR traces at 1 kHz (a 3.6 N press with noise and spikes) and 25 sweeps
    x 28 pairs of estimates with the paper sweep's windows and the dry run's motion marks."""
    rng = np.random.default_rng(13)
    t = np.arange(8540) / 1000.0
    force = 3.6 * np.clip(np.minimum((t - 2.05) / 1.7, (5.85 - t) / 0.8), 0.0, 1.0)
    model_v = 5.0 * force / (force + 1.0)  # the default FSR divider
    fsr_v = model_v + 0.003 * rng.standard_normal((presses, t.size))
    spikes = rng.integers(0, t.size, (presses, 4))
    np.put_along_axis(fsr_v, spikes, rng.uniform(0.5, 2.0, spikes.shape), axis=1)
    start = 22 + np.arange(25)[:, None] * 3416 + np.arange(28)[None, :] * 122
    windows = np.stack([start, start + 100], axis=-1)
    r = rng.uniform(2e3, 8e3, (presses, 25, 28)) * (1 + 1e-3 * rng.standard_normal((presses, 25, 28)))
    flags = np.where(rng.random(r.shape) < 0.002, 2, 0).astype(np.uint8)
    np.savez(path, fsr_v=fsr_v, r=r, flags=flags, windows=windows, marks=np.array([20500, 38200, 50200, 77700]))


def run_json(argv: list[str], checkout: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    out = subprocess.run(argv, cwd=checkout, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def wall_s(argv: list[str], checkout: Path, cwd: Path) -> float:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    t0 = time.perf_counter()
    subprocess.run(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t0


def labelling_table(checkouts: dict[str, Path], presses: int, rounds: int) -> None:
    py = sys.executable
    best: dict[str, dict[str, float]] = {name: {} for name in checkouts}
    digests: dict[str, set[str]] = {"labels": set(), "physical limit": set()}

    def keep(name: str, key: str, value: float) -> None:
        best[name][key] = min(best[name].get(key, float("inf")), value)

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        inputs = Path(tmp) / "records.npz"
        labelling_inputs(inputs, presses)
        for _ in range(rounds):
            for name, checkout in checkouts.items():
                got = run_json([py, "-c", LABELLING_CHILD, str(inputs), "5"], checkout)
                digests["labels"].add(got.pop("digest"))
                for key, value in got.items():
                    keep(name, key, value)
                got = run_json([py, "-c", PHYSLIMIT_CHILD, str(checkout / "protocols" / "paper.toml"), "2"], checkout)
                digests["physical limit"].add(got["digest"])
                keep(name, "physical_limit_s", got["physical_limit_s"])
                keep(
                    name, "help_s", min(wall_s([py, "-m", "neatskin", "--help"], checkout, checkout) for _ in range(3))
                )
                keep(name, "import_s", wall_s([py, "-c", "import neatskin"], checkout, checkout))
                first_press = [py, "-m", "neatskin", "campaign", "run", "protocols/paper.toml", "--dry-run"]
                first_press += ["--no-report", "--quiet", "--limit", "1", "--out", str(Path(tmp) / f"one-{name}")]
                keep(name, "one_press_s", wall_s(first_press, checkout, checkout))
                shutil.rmtree(Path(tmp) / f"one-{name}", ignore_errors=True)
    load_after = os.getloadavg()
    rows = [
        ("fsr_label ms/press", "fsr_label"),
        ("press_values ms/press", "press_values"),
        ("first fsr_label ms (imports)", "first_ms"),
        ("write_physical_limit s", "physical_limit_s"),
        ("neatskin --help s", "help_s"),
        ("import neatskin s", "import_s"),
        ("dry run, 1 press s", "one_press_s"),
    ]
    print(
        f"\nthe dry run's labelling ({presses} paper-like records), physical limit (paper plan) and start-up; "
        f"best of {rounds} round(s); load before {load_before[0]:.2f}, after {load_after[0]:.2f}"
    )
    names = list(checkouts)
    print(f"{'':>30}" + "".join(f"{n:>12}" for n in names) + (f"{'ratio':>9}" if len(names) == 2 else ""))
    for label, key in rows:
        values = [best[n][key] for n in names]
        ratio = f"{values[0] / values[1]:>8.2f}x" if len(names) == 2 and values[1] else ""
        print(f"{label:>30}" + "".join(f"{v:>12.3f}" for v in values) + ratio)
    total = [best[n]["fsr_label"] + best[n]["press_values"] for n in names]
    print(f"{'labelling ms/press (target 0.3)':>30}" + "".join(f"{v:>12.3f}" for v in total))
    for what, seen in digests.items():
        if len(names) > 1:
            print(f"{what}: {'identical outputs' if len(seen) == 1 else 'OUTPUTS DIFFER'} across checkouts")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sweeps and presses")
    parser.add_argument("--labelling", action="store_true", help="only the dry run's labelling / limit / start-up")
    parser.add_argument("--against", type=Path, help="another checkout to measure the labelling side by side with")
    parser.add_argument("--rounds", type=int, default=2, help="alternating rounds per checkout (best is kept)")
    args = parser.parse_args()
    checkouts = {"this": REPO, **({"against": args.against.resolve()} if args.against else {})}
    if args.labelling:
        labelling_table(checkouts, 50 if args.quick else 200, args.rounds)
        return
    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    wiring = load_wiring(REPO / "protocols" / "wiring" / "paper.toml", layout)
    accuracy_table(wiring, 20 if args.quick else 200, 3 if args.quick else 5)
    pipeline_table(wiring, 5 if args.quick else 40, 3)
    labelling_table(checkouts, 50 if args.quick else 200, args.rounds)


if __name__ == "__main__":
    main()

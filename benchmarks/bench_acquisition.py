"""Acquisition benchmark: resistance error against processing time for RMS and lock-in at several live-window
lengths, and the whole per-press pipeline's throughput as a multiple of real time (10 kHz x 3 channels).

    .venv/bin/python benchmarks/bench_acquisition.py [--quick]

Everything runs on one core, side by side in one run. Target: the pipeline >= 200 x real time.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sweeps and presses")
    args = parser.parse_args()
    layout = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    wiring = load_wiring(REPO / "protocols" / "wiring" / "paper.toml", layout)
    accuracy_table(wiring, 20 if args.quick else 200, 3 if args.quick else 5)
    pipeline_table(wiring, 5 if args.quick else 40, 3)


if __name__ == "__main__":
    main()

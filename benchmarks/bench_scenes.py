"""Benchmark: the cost of each variability source on the paper campaign (features path), side by side in one run.

    python benchmarks/bench_scenes.py                 # 200 presses per scene
    python benchmarks/bench_scenes.py --presses 400
    python benchmarks/bench_scenes.py --fit out/paper     # and time the skin fit on a finished campaign

Runs protocols/paper.toml as a dry run for --presses presses in the `ideal` scene, in `ideal`
with one source switched on at its `paper-like` value (mains pickup, off in `paper-like`, at
5 mV), and in `paper-like` (every source it uses), and
prints per scene: the wall time of the run, the simulated skin + DAQ time per press (the dry
recorder's `end`: the skin along the press's trajectory, the DAQ's estimates, the FSR trace)
and its ratio to `ideal`. The first row is `ideal` with the network solver held on its GTH
path, as the dry probe ran before the grounded small-batch path (issue 13): the ratio shows
what that path saves per press.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.sim.scene import PAPER_LIKE

REPO = Path(__file__).resolve().parent.parent
# sources that paper-like leaves off are measured at a typical value
OFF_IN_PAPER_LIKE = {"mains_pickup_mv": 5.0}
SOURCES = {
    "placement error": ("placement_error_mm",),
    "depth jitter": ("depth_jitter_mm",),
    "fabrication spread": ("fabrication_spread_fraction",),
    "sealed fluid": ("displaced_fluid_fraction",),
    "drift (temperature, evaporation)": ("temperature_drift_k_per_h", "evaporation_fraction_per_h", "press_interval_s"),
    "viscoelastic dents": ("hysteresis_fraction", "relaxation_time_s", "press_interval_s"),
    "double layer": ("double_layer_capacitance_uf",),
    "V/I skew": ("adc_skew_us",),
    "mains pickup": ("mains_pickup_mv",),
}


def scene_protocol(root: Path, name: str, preset: str, knobs: dict[str, float]) -> Path:
    text = (REPO / "protocols" / "paper.toml").read_text()
    text = text.replace('preset = "paper-like"', f'preset = "{preset}"')
    text = text.rstrip("\n") + "\n" + "".join(f"{k} = {v!r}\n" for k, v in knobs.items())
    path = root / f"{name}.toml"
    path.write_text(text)
    return path


def timed_run(path: Path, out: Path, presses: int) -> tuple[float, float]:
    """(wall s, skin + DAQ s per press) of a dry run of the first `presses` presses."""
    from neatskin.sim import recorder as sim_recorder

    spent = [0.0]
    original = sim_recorder.SimulatedRecorder.end

    def end(self):
        t0 = time.perf_counter()
        try:
            return original(self)
        finally:
            spent[0] += time.perf_counter() - t0

    sim_recorder.SimulatedRecorder.end = end
    try:
        t0 = time.perf_counter()
        run_campaign(load_protocol(path), out, progress=False, report=False, limit=presses)
        wall = time.perf_counter() - t0
    finally:
        sim_recorder.SimulatedRecorder.end = original
    return wall, spent[0] / presses


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", type=int, default=200)
    parser.add_argument(
        "--fit", metavar="CAMPAIGN_DIR", default=None, help="also time `neatskin skin fit` on this finished campaign"
    )
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-scenes-"))
    try:
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(REPO / "protocols" / sub, work / sub)
        scenes: list[tuple[str, Path, bool]] = [
            ("ideal, GTH solver (before)", scene_protocol(work, "ideal-gth", "ideal", {}), True),
            ("ideal", scene_protocol(work, "ideal", "ideal", {}), False),
        ]
        for label, keys in SOURCES.items():
            knobs = {k: PAPER_LIKE[k] or OFF_IN_PAPER_LIKE.get(k, 0.0) for k in keys}
            scenes.append((f"ideal + {label}", scene_protocol(work, f"source-{len(scenes)}", "ideal", knobs), False))
        scenes.append(("paper-like (every source)", scene_protocol(work, "paper-like", "paper-like", {}), False))
        print(f"bench_scenes: paper campaign, features path, first {args.presses} presses per scene")
        print(f"  {'scene':<40s} {'wall s':>8s} {'skin+DAQ ms/press':>18s} {'ratio to ideal':>15s}")
        import neatskin.skin.network as network

        timed_run(scenes[1][1], work / "warm-up", min(args.presses, 20))  # imports and caches, untimed
        rows = []
        for k, (label, path, gth) in enumerate(scenes):
            saved = network.GROUNDED_MAX_PRESSES
            if gth:
                network.GROUNDED_MAX_PRESSES = 0
            try:
                wall, per_press = timed_run(path, work / f"run-{k}", args.presses)
            finally:
                network.GROUNDED_MAX_PRESSES = saved
            rows.append((label, wall, per_press))
        ideal = next(r[2] for r in rows if r[0] == "ideal")
        for label, wall, per_press in rows:
            print(f"  {label:<40s} {wall:>8.1f} {1e3 * per_press:>18.2f} {per_press / ideal:>15.2f}")
        if args.fit:
            from neatskin.skin.fit import fit_skin

            t0 = time.perf_counter()
            fit = fit_skin(args.fit)
            print(
                f"skin fit on {args.fit}: {time.perf_counter() - t0:.1f} s (target 30 s); placement "
                f"{fit.placement_error_mm.value:.3g} mm, pinch_gain {fit.pinch_gain.value:.3g}, "
                f"drift {fit.drift_per_h.value:.3g} /h"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

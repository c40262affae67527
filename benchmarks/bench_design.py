"""Design study benchmark: candidates per second on 3 x 3, 10 x 10 and 30 x 30 grids, in one process, with joblib
(2 processes) and on a 2-worker distributed.LocalCluster, side by side in one run; the bound map of one 30 x 30
candidate on a 50 x 50 press grid (target < 5 s), with the adjoint Jacobian against finite differences of full
network solves; and optionally the worked 5 x 5 study (target < 10 min).

    python benchmarks/bench_design.py [--candidates 6] [--worked]

BLAS threads are pinned to 1 (the machine may be shared); study runs write no PNGs (compute only). Each study
time is one run (a study is many candidates already); the bound map time is the best of --repeats.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from neatskin.design.candidates import expand  # noqa: E402
from neatskin.design.evaluate import evaluate_candidate, press_grid_mm  # noqa: E402
from neatskin.design.runner import run_study  # noqa: E402
from neatskin.design.sensitivity import press_jacobian  # noqa: E402
from neatskin.design.study import Study, load_study, study_from_dict  # noqa: E402
from neatskin.skin.layouts import grid_layout  # noqa: E402
from neatskin.skin.model import SkinModel  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def sweep_study(n: int, candidates: int) -> Study:
    """A study of `candidates` fixed-placement candidates on an n x n grid (25 x 25 presses each)."""
    boundary = 4 * (n - 1)
    counts = sorted({max(2, min(boundary, c)) for c in (4, 6, 8, 10, 12, 16, 20, 24)})[:candidates]
    return study_from_dict(
        {
            "study": {"name": f"bench{n}", "press_grid": 25, "seed": 1},
            "layouts": {"sizes": [[n, n]], "pitch_mm": [15.0]},
            "electrodes": {"counts": counts, "strategies": ["boundary"]},
        },
        source=f"<bench {n} x {n}>",
    )


def timed_run(study: Study, **kwargs) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        run_study(study, Path(tmp) / "out", pngs=False, **kwargs)
        return time.perf_counter() - start


def candidates_per_second(sizes: list[int], candidates: int) -> None:
    from distributed import LocalCluster

    print(
        f"\n== candidates per second ({candidates} boundary candidates per grid, 25 x 25 presses each; a whole "
        "study: durable parts, candidates.parquet, report and Pareto plot included)"
    )
    print(f"{'grid':>8} {'1 process':>12} {'joblib x2':>12} {'dask 2 workers':>16} {'joblib/1':>9} {'dask/1':>7}")
    timed_run(sweep_study(3, 1))  # warm up: imports, matplotlib's first figure
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        for n in sizes:
            study = sweep_study(n, candidates)
            count = len(expand(study))
            one = count / timed_run(study)
            two = count / timed_run(study, jobs=2)
            dask = count / timed_run(study, scheduler="dask", address=cluster.scheduler_address)
            print(f"{n:>3} x {n:<3} {one:>12.2f} {two:>12.2f} {dask:>16.2f} {two / one:>9.2f} {dask / one:>7.2f}")


def bound_map_30(repeats: int) -> None:
    print("\n== one 30 x 30 candidate: bound map on a 50 x 50 press grid (target < 5 s)")
    study = study_from_dict(
        {
            "study": {"name": "b30", "press_grid": 50},
            "layouts": {"sizes": [[30, 30]]},
            "electrodes": {"counts": [16], "strategies": ["boundary"]},
        },
        source="<bench>",
    )
    candidate = expand(study)[0]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = evaluate_candidate(study, candidate)
        times.append(time.perf_counter() - start)
    print(
        f"evaluate_candidate (deformation model, 16 electrodes, 120 pairs, 2500 presses): best {min(times):.2f} s "
        f"of {repeats}; median bound {result.row['bound_median_mm']:.3g} mm"
    )
    layout = grid_layout(
        30, 30, electrodes=[tuple(int(v) for v in n.split(",")) for n in result.row["electrode_nodes"].split(";")]
    )
    x, y = press_grid_mm(layout, 50)
    rng = np.random.default_rng(0)
    subset = rng.choice(x.size, 20, replace=False)
    start = time.perf_counter()
    pj = press_jacobian(layout, layout.electrode_junctions, x, y, 3.5, 2.75, "deformation")
    adjoint_s = (time.perf_counter() - start) / x.size
    start = time.perf_counter()
    reference = SkinModel(layout).jacobian_mm(x[subset], y[subset], 3.5)  # 4 full sparse solves per press
    fd_s = (time.perf_counter() - start) / subset.size
    pe = layout.pair_electrode_index
    ours = pj.pair_jacobian(pe[:, 0], pe[:, 1])[subset, :, :2]
    err = np.abs(ours - reference).max() / np.abs(reference).max()
    print(f"{'method':<44} {'ms/press':>10} {'ratio':>8}")
    print(f"{'adjoint + Woodbury (x, y, depth)':<44} {adjoint_s * 1e3:>10.3f} {1.0:>8.1f}")
    print(f"{'central differences of full solves (x, y)':<44} {fd_s * 1e3:>10.3f} {fd_s / adjoint_s:>8.1f}")
    print(f"largest difference between the two: {err:.1e} of the largest |dR/dx|")


def worked_study() -> None:
    print("\n== the worked 5 x 5 study (protocols/studies/grid5.toml, learned error included; target < 10 min)")
    study = load_study(REPO / "protocols" / "studies" / "grid5.toml")
    for jobs in (1, 2):
        seconds = timed_run(study, jobs=jobs)
        print(f"jobs={jobs}: {len(expand(study))} candidates in {seconds:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", type=int, default=6, help="candidates per grid size")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[3, 10, 30])
    parser.add_argument("--worked", action="store_true", help="also time the worked 5 x 5 study")
    args = parser.parse_args()
    bound_map_30(args.repeats)
    candidates_per_second(args.sizes, args.candidates)
    if args.worked:
        worked_study()


if __name__ == "__main__":
    main()

"""Issue 27's open question, measured: is the inversion's time spent reaching a minimum's basin or converging in it?

Every press of a dry run is inverted twice, in one process, one BLAS thread (as a report lane):
- as the report does (`skin_inversion`: 2 starts from a 1 mm x 5-depth grid, a second pass for high residuals);
- from a start next to its answer: the model tabulated on a fine grid (0.25 mm x 9 depths by default, over the
  same box), each press's best fine point found in a window around its 2 coarse starts, then the same solver
  (`invsolve.refine`) from that one point, at several tolerances.
If the second still needs most of the first's model rows a press, the iterations go to converging (the large
residuals of the model mismatch: docs/baselines.md), not to finding the basin, and no start strategy closes the 20x.
The table is not counted as a model row (it could be cached per skin); its CPU is printed.

    python benchmarks/inversion_near_starts.py RUN [RUN ...] [--step-mm 0.25] [--depths 9]

RUN: a paper dry run (`neatskin campaign run protocols/paper.toml --dry-run --no-report -o RUN`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from neatskin.baselines.dataset import load_baseline_data
from neatskin.baselines.inversion import _diverse_starts, skin_inversion
from neatskin.baselines.invsolve import model_dr, refine
from neatskin.skin.model import SkinModel

TOLERANCES_MM = (1e-5, 1e-3, 1e-2)


def near_starts(skin, baseline, dr, lo, hi, step_mm, n_depths):
    """(table CPU s, search CPU s, starts (n, 3), their dR (n, pairs)): each press's best point of a fine table."""
    axes = [np.linspace(lo[i], hi[i], int(round((hi[i] - lo[i]) / step_mm)) + 1) for i in (0, 1)]
    axes.append(np.linspace(lo[2], hi[2], n_depths))
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    started = time.process_time()
    table = model_dr(skin, baseline, grid.reshape(-1, 3)).reshape(*grid.shape[:3], -1)
    table_s = time.process_time() - started
    started = time.process_time()
    stride, depth_stride = int(round(1.0 / step_mm)), max(1, (n_depths - 1) // 4)
    coarse = grid[::stride, ::stride, ::depth_stride]
    coarse_dr = table[::stride, ::stride, ::depth_stride]
    starts = _diverse_starts(
        coarse.reshape(-1, 3)[:, :2], coarse_dr.reshape(-1, table.shape[-1]), dr, 2, 3.0, per_xy=coarse.shape[2]
    )
    ci, cj = np.unravel_index(starts // coarse.shape[2], coarse.shape[:2])
    window = np.arange(-stride, stride + 1)
    best_cost = np.full(len(dr), np.inf)
    best = np.zeros(len(dr), dtype=np.int64)
    for k in range(starts.shape[1]):
        ii = np.clip(ci[:, k, None] * stride + window, 0, grid.shape[0] - 1)
        jj = np.clip(cj[:, k, None] * stride + window, 0, grid.shape[1] - 1)
        for s in range(0, len(dr), 256):
            rows = slice(s, s + 256)
            diff = table[ii[rows][:, :, None], jj[rows][:, None, :]] - dr[rows][:, None, None, None, :]
            cost = np.einsum("bijdp,bijdp->bijd", diff, diff).reshape(len(diff), -1)
            at = np.argmin(cost, axis=1)
            ai, aj, ad = np.unravel_index(at, (len(window), len(window), n_depths))
            m = np.arange(len(at))
            flat = np.ravel_multi_index((ii[rows][m, ai], jj[rows][m, aj], ad), grid.shape[:3])
            lower = cost[m, at] < best_cost[rows]
            best_cost[rows] = np.where(lower, cost[m, at], best_cost[rows])
            best[rows] = np.where(lower, flat, best[rows])
    search_s = time.process_time() - started
    return table_s, search_s, grid.reshape(-1, 3)[best], table.reshape(-1, table.shape[-1])[best]


def one_run(run: str, step_mm: float, n_depths: int) -> None:
    data = load_baseline_data(run)
    fidelity, probe = data.skin_fidelity or "deformation", data.probe_radius_mm or 2.75
    started = time.process_time()
    report = skin_inversion(data.layout, data.X, fidelity=fidelity, probe_radius_mm=probe)
    report_s = time.process_time() - started
    n = len(data.X)
    print(f"\n{run}: {n} presses, load {open('/proc/loadavg').read().split()[0]}")
    print("| solver | CPU s | model rows a press | mean error mm | moved > 1e-3 mm | moved > 0.1 mm | residual worse |")
    print("|---|---|---|---|---|---|---|")
    error = np.linalg.norm(report.xy_mm - data.y, axis=1).mean()
    print(
        f"| as the report (2 coarse starts, second pass) | {report_s:.2f} | {report.n_model_evaluations / n:.1f} | "
        f"{error:.4f} | | | |"
    )
    skin = SkinModel(data.layout, fidelity=fidelity, probe_radius_mm=probe)
    baseline = np.asarray(skin.pair_resistance_ohm(0.0, 0.0, 0.0), float)[0]
    x0, y0, x1, y1 = data.layout.bounds_mm
    lo = np.array([x0 - 0.5, y0 - 0.5, 0.05 * data.layout.thickness_mm])
    hi = np.array([x1 + 0.5, y1 + 0.5, 0.95 * data.layout.thickness_mm])
    table_s, search_s, start, start_dr = near_starts(skin, baseline, data.X, lo, hi, step_mm, n_depths)
    print(
        f"(fine table {step_mm:g} mm x {n_depths} depths: {table_s:.2f} s CPU, not counted below; "
        f"the window search {search_s:.2f} s, counted)"
    )
    for tolerance in TOLERANCES_MM:
        p, r = start.copy(), start_dr - data.X
        cost = np.einsum("np,np->n", r, r)
        started = time.process_time()
        cost, _, evaluations = refine(skin, baseline, p, r, cost, data.X, lo, hi, 40, 1e-3, tolerance)
        refine_s = time.process_time() - started
        residual = np.sqrt(cost / data.X.shape[1])
        moved = np.linalg.norm(p[:, :2] - report.xy_mm, axis=1)
        worse = np.mean(residual > report.residual_ohm * (1 + 1e-6)) * 100
        error = np.linalg.norm(p[:, :2] - data.y, axis=1).mean()
        print(
            f"| one start from the fine table, tolerance {tolerance:g} mm | {search_s + refine_s:.2f} | "
            f"{evaluations / n:.1f} | {error:.4f} | {np.mean(moved > 1e-3) * 100:.1f} % | "
            f"{np.mean(moved > 0.1) * 100:.1f} % | {worse:.1f} % |"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--step-mm", type=float, default=0.25)
    parser.add_argument("--depths", type=int, default=9)
    args = parser.parse_args(argv)
    threadpool_limits(1)
    for run in args.runs:
        one_run(run, args.step_mm, args.depths)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Issue 27's seventh round, measured: the inversion on a tabulated surrogate of the skin model (method="surrogate").

    python benchmarks/inversion_surrogate.py RUN [RUN ...] [--grids 0.5x9 0.25x9 ...] [--points 20000]

For the first RUN's skin model (the parametric SkinModel the inversion assumes):
- per table grid (x/y step mm x depths): its nodes, CPU to build it (model rows, then the spline's coefficients),
  its size, and its relative dR error at random off-grid points of the inversion's box (the largest pair error over
  the row's largest |dR|), by depth fifth, near the depth bound, and by how near the probe's edge passes a channel;
  the gradient's error against the model's analytic Jacobian.
Per RUN (one process, one BLAS thread, as a report lane): `skin_inversion` as the report calls it (method="batched")
and with method="surrogate" (the table warm, from a fresh cache built first and timed), CPU split into the table,
the search on the table and the polish on the true model; model rows a press; and the answers' distances to the
batched ones (largest coordinate), the share ending at a higher residual, the mean position error.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np
from threadpoolctl import threadpool_limits

from neatskin.baselines.dataset import load_baseline_data
from neatskin.baselines.inversion import skin_inversion
from neatskin.baselines.invsolve import model_dr, model_drj
from neatskin.baselines.invtable import build_table
from neatskin.skin.model import SkinModel


def _box(layout):
    x0, y0, x1, y1 = layout.bounds_mm
    lo = np.array([x0 - 0.5, y0 - 0.5, 0.05 * layout.thickness_mm])
    hi = np.array([x1 + 0.5, y1 + 0.5, 0.95 * layout.thickness_mm])
    return lo, hi


def _channel_gap_mm(layout, xy, radius_mm):
    """Per row: |distance to the nearest channel centreline - probe radius| (0: the probe's edge on a channel)."""
    gap = np.full(len(xy), np.inf)
    for ch in layout.channels:
        a = np.array([layout.junctions[ch.a].x_mm, layout.junctions[ch.a].y_mm])
        b = np.array([layout.junctions[ch.b].x_mm, layout.junctions[ch.b].y_mm])
        t = np.clip(((xy - a) @ (b - a)) / max((b - a) @ (b - a), 1e-12), 0.0, 1.0)
        d = np.linalg.norm(xy - (a + t[:, None] * (b - a)), axis=1)
        gap = np.minimum(gap, np.abs(d - radius_mm))
    return gap


def _q(rel, rows) -> str:
    return f"{np.median(rel[rows]):.1e} / {np.quantile(rel[rows], 0.99):.1e}"


def accuracy(run: str, grids: list[str], n_points: int) -> None:
    data = load_baseline_data(run)
    skin = SkinModel(
        data.layout, fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75
    )
    baseline = np.asarray(skin.pair_resistance_ohm(0.0, 0.0, 0.0), float)[0]
    lo, hi = _box(data.layout)
    rng = np.random.default_rng(7)
    points = lo + rng.random((n_points, 3)) * (hi - lo)
    started = time.process_time()
    truth = model_dr(skin, baseline, points)
    row_us = 1e6 * (time.process_time() - started) / n_points
    value, jac = model_drj(skin, baseline, points[:4000])
    scale = np.maximum(np.abs(truth).max(axis=1), 1e-9)
    depth_fifth = np.minimum(((points[:, 2] - lo[2]) / (hi[2] - lo[2]) * 5).astype(int), 4)
    gap = _channel_gap_mm(data.layout, points[:, :2], skin.probe_radius_mm)
    print(
        f"\n{run}: surrogate accuracy at {n_points} random points (model {row_us:.1f} us a value row); load {os.getloadavg()[0]:.2f}"
    )
    print("relative error: the largest pair's |table - model| over the row's largest |dR|; median / 99th percentile")
    head = "| grid | nodes | build CPU s (model + spline) | MB | all | depth fifths 1..5 | top 2 % depth | edge on a channel (< 0.25 mm) | gradient |"
    print(head)
    print("|---|---|---|---|---|---|---|---|---|")
    for spec in grids:
        step, depths = spec.split("x")
        started = time.process_time()
        table = build_table(skin, baseline, lo, hi, float(step), int(depths))
        build_s = time.process_time() - started
        got = table.evaluate(points, 1)
        rel = np.abs(got[:, 0] - truth).max(axis=1) / scale
        fifths = ", ".join(
            f"{np.median(rel[depth_fifth == k]):.0e}/{np.quantile(rel[depth_fifth == k], 0.99):.0e}" for k in range(5)
        )
        deep = points[:, 2] > hi[2] - 0.02 * (hi[2] - lo[2])
        grad = got[:4000, 1:4].transpose(0, 2, 1)
        ok = np.all(np.isfinite(jac), axis=(1, 2))
        grel = np.abs(grad[ok] - jac[ok]).max(axis=(1, 2)) / np.abs(jac[ok]).max(axis=(1, 2))
        nodes = int(np.prod(table.shape))
        mb = (table.values.nbytes + table.coef.nbytes) / 1e6
        print(
            f"| {spec} | {nodes} | {build_s:.2f} | {mb:.0f} | {_q(rel, slice(None))} | {fifths} | {_q(rel, deep)} | {_q(rel, gap < 0.25)} | "
            f"{np.median(grel):.1e} / {np.quantile(grel, 0.99):.1e} |"
        )


class _Counters:
    """CPU per part of the surrogate path: functions wrapped in place, process time summed (nested parts included)."""

    def __init__(self, parts):
        self.cpu: dict[str, float] = {}
        self.parts = parts
        self.saved = []

    def __enter__(self):
        for owner, name, label in self.parts:
            real = getattr(owner, name)
            self.saved.append((owner, name, real))

            def timed(*args, _real=real, _label=label, **kwargs):
                started = time.process_time()
                try:
                    return _real(*args, **kwargs)
                finally:
                    self.cpu[_label] = self.cpu.get(_label, 0.0) + time.process_time() - started

            setattr(owner, name, timed)
        return self

    def __exit__(self, *exc):
        for owner, name, real in self.saved:
            setattr(owner, name, real)


def breakdown(run: str) -> None:
    """Where the surrogate path's CPU goes (warm table), one run, with counters."""
    from neatskin.baselines import inversion, invpolish, invtable

    data = load_baseline_data(run)
    kw = dict(fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75)
    parts = [
        (invtable, "load_table", "table load (warm)"),
        (inversion, "_diverse_starts", "start search"),
        (inversion, "refine", "search on the table (solver + table rows)"),
        (invpolish, "refine", "polish on the model (solver + model rows + table Hessians)"),
        (invtable.SplineTable, "evaluate", "table rows (search and polish)"),
        (invtable.TableSkin, "pair_resistance_ohm", "grid rows (table look-ups)"),
    ]
    skin_inversion(data.layout, data.X[:8], **kw, method="surrogate")  # the table in the cache
    with _Counters(parts) as counters:
        started = time.process_time()
        skin_inversion(data.layout, data.X, **kw, method="surrogate")
        total = time.process_time() - started
    print(f"\n{run}: where the surrogate path's CPU goes (warm), load {os.getloadavg()[0]:.2f}; total {total:.2f} s")
    for label, cpu in counters.cpu.items():
        print(f"| {label} | {cpu:.3f} s | {100 * cpu / total:.0f} % |")


def row_costs(run: str, rows: int = 2048, repeats: int = 7) -> None:
    """us a row, best of `repeats`: the table's value / with gradient / with Hessian for the 28 pairs, and what one
    row of a per-press scalar-cost spline would cost in numpy (f = |dR|^2 - 2 d.dR + |d|^2: the same gather of the
    row's 64 x 28 coefficients, their product with the press's d, and the 10 derivative weights on 64 numbers)."""
    from neatskin.baselines.invtable import _ORDER_INDEX, _basis

    data = load_baseline_data(run)
    skin = SkinModel(
        data.layout, fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75
    )
    baseline = np.asarray(skin.pair_resistance_ohm(0.0, 0.0, 0.0), float)[0]
    lo, hi = _box(data.layout)
    table = build_table(skin, baseline, lo, hi, 0.5, 9)
    rng = np.random.default_rng(3)
    p = lo + rng.random((rows, 3)) * (hi - lo)
    d = data.X[rng.integers(0, len(data.X), rows)]

    def best(f) -> float:
        times = []
        for _ in range(repeats):
            started = time.process_time()
            f()
            times.append(time.process_time() - started)
        return 1e6 * min(times) / rows

    pairs = table.coef.shape[-1]
    flat = table.coef.reshape(-1, pairs)
    runs = np.lib.stride_tricks.as_strided(
        flat, shape=(len(flat) - 3, 4 * pairs), strides=flat.strides, writeable=False
    )
    ny, nd = table.coef.shape[1:3]

    def scalar_row():
        cells, weights = [], []
        for a in range(3):
            cell, w = _basis((p[:, a] - table.lo[a]) / table.step[a], table.shape[a])
            cells.append(cell)
            weights.append(w)
        four = np.arange(4)
        first = (cells[0][:, None, None] + four[None, :, None]) * ny + cells[1][:, None, None] + four[None, None, :]
        block = runs[(first * nd + cells[2][:, None, None]).reshape(rows, 16)].reshape(rows, 64, pairs)
        coef = np.einsum("mkp,mp->mk", block, d)  # (|dR|^2's own block would add one 64-vector gather)
        o = _ORDER_INDEX
        wx, wy, wd = weights
        combos = wx[:, o[0], :, None, None] * wy[:, o[1], None, :, None] * wd[:, o[2], None, None, :]
        return np.einsum("mkc,mc->mk", combos.reshape(rows, 10, 64), coef)

    model_s = best(lambda: model_drj(skin, baseline, p))
    print(
        f"\n{run}: us a row (best of {repeats}, {rows} rows, load {os.getloadavg()[0]:.2f}): model value and gradient "
        f"{model_s:.1f}; table value {best(lambda: table.evaluate(p, 0)):.1f}, with gradient "
        f"{best(lambda: table.evaluate(p, 1)):.1f}, with Hessian {best(lambda: table.evaluate(p, 2)):.1f}; a scalar-cost "
        f"row with gradient and Hessian {best(scalar_row):.1f}"
    )


def polish_caps(run: str, caps=(1, 2, 3, 4, 6)) -> None:
    """How far a polish cut short lands from the full one: the polish's steps capped (the search unchanged)."""
    from neatskin.baselines import invpolish

    data = load_baseline_data(run)
    kw = dict(fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75)
    full = skin_inversion(data.layout, data.X, **kw, method="surrogate")
    at = np.c_[full.xy_mm, full.depth_mm]
    real = invpolish.refine
    print(f"\n{run}: the polish capped (the full polish: {full.n_model_evaluations / len(at):.2f} model rows a press)")
    print(
        "| polish steps | model rows a press | within 1e-5 mm of the full polish | 1e-4 mm | 1e-3 mm | higher residual |"
    )
    print("|---|---|---|---|---|---|")
    for cap in caps:

        def capped(*args, _cap=cap, **kwargs):
            args = list(args)
            args[8] = _cap  # max_iterations
            return real(*args, **kwargs)

        invpolish.refine = capped
        try:
            res = skin_inversion(data.layout, data.X, **kw, method="surrogate")
        finally:
            invpolish.refine = real
        apart = np.abs(np.c_[res.xy_mm, res.depth_mm] - at).max(axis=1)
        print(
            f"| {cap} | {res.n_model_evaluations / len(at):.2f} | {np.mean(apart < 1e-5) * 100:.1f} % | "
            f"{np.mean(apart < 1e-4) * 100:.1f} % | {np.mean(apart < 1e-3) * 100:.1f} % | "
            f"{np.mean(res.residual_ohm > full.residual_ohm * (1 + 1e-6)) * 100:.1f} % |"
        )


def inversions(run: str) -> None:
    data = load_baseline_data(run)
    kw = dict(fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75)
    n = len(data.X)
    with tempfile.TemporaryDirectory() as cache:
        os.environ["NEATSKIN_CACHE"] = cache
        results = {}
        for name, extra in (
            ("batched", {"method": "batched"}),
            ("surrogate, cold (table built)", {"method": "surrogate"}),
            ("surrogate, warm (table cached)", {"method": "surrogate"}),
            ("surrogate, warm, secant polish", {"method": "surrogate", "polish": "secant"}),
            ("batched", {"method": "batched"}),
            ("surrogate, warm (table cached)", {"method": "surrogate"}),
        ):
            started = time.process_time()
            res = skin_inversion(data.layout, data.X, **kw, **extra)
            cpu = time.process_time() - started
            if name in results:
                results[name] = (min(cpu, results[name][0]), res)
            else:
                results[name] = (cpu, res)
    ref = results["batched"][1]
    print(f"\n{run}: {n} presses, one BLAS thread, load {os.getloadavg()[0]:.2f} (best of 2 where run twice)")
    print(
        "| inversion | CPU s | model rows a press | table rows a press | mean error mm | within 1e-3 mm of batched | moved > 0.1 mm | higher residual | lower residual |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, (cpu, res) in results.items():
        apart = np.abs(np.c_[res.xy_mm, res.depth_mm] - np.c_[ref.xy_mm, ref.depth_mm]).max(axis=1)
        error = np.linalg.norm(res.xy_mm - data.y, axis=1).mean()
        worse = np.mean(res.residual_ohm > ref.residual_ohm * (1 + 1e-6)) * 100
        better = np.mean(res.residual_ohm < ref.residual_ohm * (1 - 1e-6)) * 100
        print(
            f"| {name} | {cpu:.2f} | {res.n_model_evaluations / n:.1f} | {res.n_surrogate_evaluations / n:.1f} | "
            f"{error:.4f} | {np.mean(apart < 1e-3) * 100:.1f} % | {np.mean(apart > 0.1) * 100:.1f} % | {worse:.1f} % | "
            f"{better:.1f} % |"
        )
    # the presses that moved: in a basin of another cost, or elsewhere in a flat valley of the same cost?
    res = results["surrogate, warm (table cached)"][1]
    apart = np.abs(np.c_[res.xy_mm, res.depth_mm] - np.c_[ref.xy_mm, ref.depth_mm]).max(axis=1)
    moved = apart > 0.1
    change = (res.residual_ohm[moved] - ref.residual_ohm[moved]) / ref.residual_ohm[moved]
    err_ref = np.linalg.norm(ref.xy_mm - data.y, axis=1)[moved]
    err_res = np.linalg.norm(res.xy_mm - data.y, axis=1)[moved]
    bound = 0.95 * data.layout.thickness_mm
    print(
        f"moved > 0.1 mm (warm): {moved.sum()} presses, {np.sum(np.abs(change) < 1e-3)} at a residual within 0.1 % of "
        f"today's ({np.sum(change < -1e-2)} lower by > 1 %, {np.sum(change > 1e-2)} higher); their median residual "
        f"{np.median(ref.residual_ohm[moved]):.1f} ohm (every press {np.median(ref.residual_ohm):.1f}); on the depth "
        f"bound {np.mean(ref.depth_mm[moved] >= bound - 1e-9) * 100:.0f} % (every press "
        f"{np.mean(ref.depth_mm >= bound - 1e-9) * 100:.0f} %); their mean error {err_ref.mean():.3f} -> "
        f"{err_res.mean():.3f} mm"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--grids", nargs="*", default=["1.0x5", "0.5x9", "0.5x17", "0.25x9"])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--no-accuracy", action="store_true")
    parser.add_argument("--polish-caps", action="store_true", help="also: the polish cut short after 1 to 6 steps")
    args = parser.parse_args(argv)
    threadpool_limits(1)
    if not args.no_accuracy:
        accuracy(args.runs[0], args.grids, args.points)
        row_costs(args.runs[0])
    for run in args.runs:
        inversions(run)
        breakdown(run)
        if args.polish_caps:
            polish_caps(run)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

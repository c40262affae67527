"""Skin simulator benchmark: presses per second and accuracy, measured side by side in one run.

    python benchmarks/bench_skin.py [--presses 100000] [--repeats 5]

Prints (1) the batched GTH solve against a per-press numpy.linalg.pinv loop on the paper's
layout, (2) the same on a 30 x 30 grid (sparse path), (3) the whole press -> R_eq pipeline at
deformation and network fidelity (target: >= 100,000 presses/s for the paper's layout at
deformation fidelity on one core), (4) the deformation integral's error against run time over
quadrature resolutions, (5) presses near full depth, (6) the physics inversion's calls (value and Jacobian,
us a row at 0.5 and 0.95 of the thickness), with --base DIR beside another checkout's skin/deformation.py and
skin/modelgrad.py loaded into the same process (alternating; --gradient-only runs just that). Runs on one core: BLAS/OpenMP threads are pinned to 1 before numpy loads.
Times are the best of --repeats runs (the machine may be shared).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from neatskin.layout import load_layout  # noqa: E402
from neatskin.skin.deformation import PinchParams, resistance_factor  # noqa: E402
from neatskin.skin.layouts import grid_layout  # noqa: E402
from neatskin.skin.model import SkinModel  # noqa: E402
from neatskin.skin.network import equivalent_resistance  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def best_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def pinv_loop(layout, conductance_s):
    """The straightforward way: per press, build the Laplacian and take its pseudo-inverse."""
    n = layout.n_junctions
    ends = layout.channel_ends
    ej = layout.electrode_junctions[layout.pair_electrode_index]
    out = np.empty((conductance_s.shape[0], ej.shape[0]))
    for p, g in enumerate(conductance_s):
        lap = np.zeros((n, n))
        np.add.at(lap, (ends[:, 0], ends[:, 0]), g)
        np.add.at(lap, (ends[:, 1], ends[:, 1]), g)
        np.add.at(lap, (ends[:, 0], ends[:, 1]), -g)
        np.add.at(lap, (ends[:, 1], ends[:, 0]), -g)
        inv = np.linalg.pinv(lap)
        out[p] = inv[ej[:, 0], ej[:, 0]] + inv[ej[:, 1], ej[:, 1]] - 2 * inv[ej[:, 0], ej[:, 1]]
    return out


def row(label, rate, note=""):
    print(f"  {label:<44s} {rate:>14,.0f} presses/s  {note}")


def solver_section(title, layout, n_batch, n_loop, repeats, rng):
    print(f"\n{title}: {layout.n_junctions} junctions, {layout.n_channels} channels, {len(layout.pairs)} pairs")
    g = 1.0 / (layout.channel_resistance_ohm * rng.uniform(1.0, 2.0, (n_batch, layout.n_channels)))
    t_batch = best_time(lambda: equivalent_resistance(layout, g), repeats)
    t_loop = best_time(lambda: pinv_loop(layout, g[:n_loop]), max(1, repeats // 2))
    r_batch = equivalent_resistance(layout, g[:n_loop])
    r_loop = pinv_loop(layout, g[:n_loop])
    rate_batch, rate_loop = n_batch / t_batch, n_loop / t_loop
    path = "dense GTH" if layout.n_junctions <= 64 else "sparse splu"
    row(f"batched solve ({path}, {n_batch} presses)", rate_batch)
    row(f"per-press numpy.linalg.pinv loop ({n_loop} presses)", rate_loop)
    print(
        f"  ratio batched / pinv: {rate_batch / rate_loop:,.1f} x;  max relative difference "
        f"{np.max(np.abs(r_loop / r_batch - 1)):.1e}"
    )


def pipeline_section(layout, n, repeats, rng):
    print(f"\npress -> R_eq pipeline, paper layout, 3.5 mm presses at random positions ({n} presses)")
    x, y = rng.uniform(0, 30, n), rng.uniform(0, 30, n)
    depth = np.full(n, 3.5)
    for fidelity in ("deformation", "network"):
        model = SkinModel(layout, fidelity=fidelity)
        t_total = best_time(lambda m=model: m.pair_resistance_ohm(x, y, depth), repeats)
        resistance = model.channel_resistance_ohm(x, y, depth)
        t_channels = best_time(lambda m=model: m.channel_resistance_ohm(x, y, depth), repeats)
        t_solve = best_time(lambda r=resistance: equivalent_resistance(layout, 1.0 / r), repeats)
        target = "  (target >= 100,000)" if fidelity == "deformation" else ""
        row(
            f"{fidelity} fidelity, end to end",
            n / t_total,
            f"channels {n / t_channels:,.0f}/s, solve {n / t_solve:,.0f}/s{target}",
        )


def quadrature_section(layout, n, repeats, rng):
    print(
        f"\ndeformation integral: error against run time ({n} presses, depth uniform 0.5..5.0 mm, "
        f"reference 64 nodes/panel)"
    )
    x, y = rng.uniform(-3, 33, n), rng.uniform(-3, 33, n)
    depth = rng.uniform(0.5, 5.0, n)
    ref = resistance_factor(layout, x, y, depth, 2.75, PinchParams(nodes_per_panel=64))
    ref_eq = equivalent_resistance(layout, 1.0 / (ref * layout.channel_resistance_ohm))
    print(
        f"  {'nodes/panel':>11s} {'nodes/channel':>13s} {'max rel err R_ch':>17s} {'max rel err R_eq':>17s} "
        f"{'presses/s':>12s}"
    )
    for q in (2, 3, 4, 6, 8, 12, 16):
        params = PinchParams(nodes_per_panel=q)
        t = best_time(lambda p=params: resistance_factor(layout, x, y, depth, 2.75, p), repeats)
        f = resistance_factor(layout, x, y, depth, 2.75, params)
        r_eq = equivalent_resistance(layout, 1.0 / (f * layout.channel_resistance_ohm))
        mark = "  <- default" if q == PinchParams().nodes_per_panel else ""
        print(
            f"  {q:>11d} {2 * 3 * q:>13d} {np.max(np.abs(f / ref - 1)):>17.1e} "
            f"{np.max(np.abs(r_eq / ref_eq - 1)):>17.1e} {n / t:>12,.0f}{mark}"
        )


def near_full_section(layout, repeats):
    """Presses near the skin's full thickness with a channel crossing or grazing the probe's edge: the error
    of the standard panels (grading switched off) and of the graded ones, against a 64-node graded reference."""
    import neatskin.skin.deformation as deformation

    depths = np.array([5.0, 5.3, 5.4, 5.45, 5.49, 5.499, 5.4999])
    offsets = np.array([0.0, 1.0, 2.0, 2.5, 2.7, 2.75, 2.8, 3.0, 4.0])
    d, off, along = (v.ravel() for v in np.meshgrid(depths, offsets, np.array([2.0, 7.5, 14.0]), indexing="ij"))
    x, y = along, off  # channel 0 of the paper layout runs along y = 0 from x = 0 to 15
    ref = resistance_factor(layout, x, y, d, 2.75, PinchParams(nodes_per_panel=64))
    print(
        f"\nnear full depth ({x.size} presses: depth 5.0..5.4999 mm of 5.5, the channel 0..4 mm from the probe axis; "
        f"reference 64 nodes/panel, graded; tests hold it to QUADPACK)"
    )
    print(f"  {'nodes/panel':>11s} {'standard panels':>16s} {'graded panels':>14s} {'presses/s graded':>17s}")
    for q in (4, 6, 8, 12):
        params = PinchParams(nodes_per_panel=q)
        saved = deformation._GRADED_FROM_P0
        deformation._GRADED_FROM_P0 = 2.0  # no press is graded: the standard panels
        try:
            plain = resistance_factor(layout, x, y, d, 2.75, params)
        finally:
            deformation._GRADED_FROM_P0 = saved
        graded = resistance_factor(layout, x, y, d, 2.75, params)
        t = best_time(lambda p=params: resistance_factor(layout, x, y, d, 2.75, p), repeats)
        err = lambda f: np.max(np.abs(f / ref - 1))  # noqa: E731
        mark = "  <- default" if q == PinchParams().nodes_per_panel else ""
        print(f"  {q:>11d} {err(plain):>16.1e} {err(graded):>14.1e} {x.size / t:>17,.0f}{mark}")


def _checkout_skin(base_dir: Path):
    """Another checkout's deformation and modelgrad as modules of their own (modelgrad bound to that deformation)."""
    import sys
    import types

    modules = []
    for name, replace in (("deformation", ()), ("modelgrad", (("neatskin.skin.deformation", "base_deformation"),))):
        path = base_dir / "neatskin" / "skin" / f"{name}.py"
        source = path.read_text()
        for old, new in replace:
            source = source.replace(old, new)
        module = types.ModuleType(f"base_{name}")
        module.__file__ = str(path)
        sys.modules[module.__name__] = module
        exec(compile(source, str(path), "exec"), module.__dict__)
        modules.append(module)
    return modules


def gradient_section(layout, rows: int, repeats: int, base_dir: Path | None) -> None:
    """us a row of the inversion's calls: the channel factors and their gradient, the value and Jacobian, the value;
    rows random presses over the skin at one depth, best of `repeats` (each a loop of calls), alternating."""
    from neatskin.skin import deformation, modelgrad

    skin = SkinModel(layout, probe_radius_mm=2.75)
    ohm = skin.channel_baseline_ohm
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 30, rows), rng.uniform(0, 30, rows)
    sides = {"this": (deformation, modelgrad)}
    if base_dir is not None:
        sides = {"base": tuple(_checkout_skin(base_dir)), **sides}

    def calls(dfm, mg, d):
        def value():
            with np.errstate(divide="ignore"):
                return equivalent_resistance(layout, 1.0 / (dfm.resistance_factor(layout, x, y, d, 2.75) * ohm))

        def jacobian():
            return mg.pair_resistance_and_gradient(layout, *mg.factor_and_gradient(layout, x, y, d, 2.75), ohm)

        return {
            "factor_and_gradient": lambda: mg.factor_and_gradient(layout, x, y, d, 2.75),
            "value + Jacobian (pair_resistance_and_jacobian_ohm)": jacobian,
            "value (pair_resistance_ohm's path)": value,
        }

    loops = max(3, 3000 // rows)
    print(f"\nphysics inversion's calls, us a row ({rows} presses, best of {repeats} x {loops} calls, alternating)")
    print(f"  {'depth':>6s} {'call':52s} " + " ".join(f"{name:>7s}" for name in sides))
    for fraction in (0.5, 0.95):
        d = np.full(rows, fraction * layout.thickness_mm)
        per_side = {name: calls(*modules, d) for name, modules in sides.items()}
        for call in per_side["this"]:
            best = dict.fromkeys(sides, np.inf)
            for _ in range(repeats):
                for name in sides:
                    fn = per_side[name][call]
                    fn()
                    best[name] = min(best[name], best_time(lambda f=fn: [f() for _ in range(loops)], 1) / loops)
            print(f"  {fraction:>5.2f}T {call:52s} " + " ".join(f"{best[k] / rows * 1e6:>7.2f}" for k in sides))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--base", type=Path, help="another checkout to compare the inversion's calls with")
    parser.add_argument("--gradient-only", action="store_true", help="only the inversion's calls")
    parser.add_argument("--rows", type=int, default=256, help="presses per call of the inversion's calls")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    paper = load_layout(REPO / "protocols" / "skins" / "paper.toml")
    print(f"bench_skin: one core, best of {args.repeats}; load {' '.join(open('/proc/loadavg').read().split()[:3])}")
    if args.gradient_only:
        gradient_section(paper, args.rows, args.repeats, args.base)
        return
    solver_section("network solver, paper layout", paper, args.presses, 2000, args.repeats, rng)
    solver_section(
        "network solver, 30 x 30 grid", grid_layout(30, 30, pitch_mm=5.0), 200, 4, max(1, args.repeats // 2), rng
    )
    pipeline_section(paper, args.presses, args.repeats, rng)
    quadrature_section(paper, min(args.presses, 20_000), args.repeats, rng)
    near_full_section(paper, args.repeats)
    gradient_section(paper, args.rows, args.repeats, args.base)


if __name__ == "__main__":
    main()

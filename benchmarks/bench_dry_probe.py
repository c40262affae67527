"""The dry run's per-press skin work, old way against new way, measured side by side in one run.

    python benchmarks/bench_dry_probe.py [--states 60] [--repeats 20]

A dry-run press asks the skin for R_eq at the few dozen distinct probe states of its sweep slots,
and before the press for the undeformed R_eq with the residual dents of earlier presses. Rows:
(1) R / R0 and the pinched length share (displaced fluid) as two quadratures against one pass
(`factor_and_length_fraction`), (2) the quadrature over presses that do not touch the skin
(depth <= 0) as before (integrated, then overwritten with 1) against skipped, by calling
`_factor_chunk` directly. Every pair of rows is checked bit for bit before it is timed. Runs on one
core (BLAS threads pinned to 1); times are the best of --repeats (the machine may be shared).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from neatskin.layout import load_layout  # noqa: E402
from neatskin.skin.deformation import (  # noqa: E402
    _PANEL_EDGES,
    PinchParams,
    _factor_chunk,
    factor_and_length_fraction,
    pinched_length_fraction,
    resistance_factor,
)
from neatskin.tomlfile import resolve_path  # noqa: E402

PROBE_RADIUS_MM = 2.75


def best_time_s(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=60, help="distinct probe states per press (default 60)")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    layout = load_layout(resolve_path("protocols/skins/paper.toml"))
    rng = np.random.default_rng(0)
    n = args.states
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
        return _factor_chunk(layout, zero, zero, zero, np.full(1, PROBE_RADIUS_MM), params, None, False, _PANEL_EDGES)

    def untouched_skipped() -> np.ndarray:
        return resistance_factor(layout, 0.0, 0.0, 0.0, PROBE_RADIUS_MM, params)

    np.testing.assert_array_equal(untouched_integrated(), untouched_skipped())

    rows = [
        (f"R/R0 + length share, {n} states", two, one),
        ("untouched press (baseline with dents)", untouched_integrated, untouched_skipped),
    ]
    print(f"{'work':42s} {'before ms':>10s} {'after ms':>10s} {'speed-up':>9s}")
    for name, before, after in rows:
        t_before, t_after = best_time_s(before, args.repeats), best_time_s(after, args.repeats)
        print(f"{name:42s} {1e3 * t_before:10.3f} {1e3 * t_after:10.3f} {t_before / t_after:8.2f}x")


if __name__ == "__main__":
    main()

"""The network solver against an independent circuit simulator: ngspice, run on SPICE netlists written from the layout.

For every press and every electrode pair (a, b) the netlist holds one copy of the network with b
as ground and a 1 A source into a, so V(a) = R_eq(a, b); the binary rawfile gives V(a) as a
full double. Skipped where the `ngspice` executable is not on PATH (Debian/Ubuntu:
`apt-get install ngspice`; no pip package provides it).

Tolerances are what ngspice can honour, not what neatskin achieves: ngspice solves the MNA
system with a floating-point sparse LU (no gmin on linear resistors), so its relative error
grows like eps times the conductance spread: ~1e-15 on equal channels, ~1e-10 over 6 decades,
~1e-9 with a 1e6x near-short, ~1e-3 with a 1e12x near-short (measured with ngspice 39). The
dense path's relative accuracy on stiff networks is tested against the exact Fraction
reference in test_skin_network.py; this file checks that the solver models the same circuit
as a SPICE simulator does.
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from neatskin.skin.layouts import grid_layout
from neatskin.skin.network import equivalent_resistance

NGSPICE = shutil.which("ngspice")
pytestmark = pytest.mark.skipif(NGSPICE is None, reason="ngspice not on PATH (apt-get install ngspice)")

R0 = 3750.0  # ohm, one channel of the paper skin


def _netlist(layout, g: np.ndarray) -> tuple[str, list[tuple[int, int, str]]]:
    ends = layout.channel_ends.tolist()
    elec = layout.electrode_junctions.tolist()
    lines = ["* neatskin network vs ngspice"]
    probes = []
    for p in range(g.shape[0]):
        for k, (ia, ib) in enumerate(layout.pair_electrode_index.tolist()):
            a, b = elec[ia], elec[ib]

            def node(j: int, b: int = b, p: int = p, k: int = k) -> str:
                return "0" if j == b else f"p{p}k{k}n{j}"

            for c, (u, v) in enumerate(ends):
                if g[p, c] > 0:
                    lines.append(
                        f"R{p}k{k}c{c} {node(u)} {node(v)} {float(1.0 / g[p, c])!r}"
                    )  # repr: the shortest exact decimal
            lines.append(f"I{p}k{k} 0 {node(a)} DC 1")  # 1 A from ground (b) into a
            probes.append((p, k, f"v({node(a)})"))
    lines += [".op", ".end", ""]
    return "\n".join(lines), probes


def _read_raw(path) -> dict[str, float]:
    data = path.read_bytes()
    start = data.index(b"Binary:\n")
    lines = data[:start].decode().splitlines()
    n_var = int(next(line for line in lines if line.startswith("No. Variables:")).split(":")[1])
    first = lines.index("Variables:") + 1
    names = [lines[first + v].split("\t")[2].lower() for v in range(n_var)]
    values = np.frombuffer(data[start + 8 : start + 8 + 8 * n_var], dtype=np.float64)
    return dict(zip(names, values.tolist()))


def ngspice_resistance(layout, conductance_s, tmp_path) -> np.ndarray:
    """R_eq (presses, pairs) in layout.pairs order, from ngspice's DC operating point."""
    g = np.atleast_2d(np.asarray(conductance_s, dtype=float))
    text, probes = _netlist(layout, g)
    cir, raw = tmp_path / "skin.cir", tmp_path / "skin.raw"
    cir.write_text(text)
    proc = subprocess.run([NGSPICE, "-b", "-r", str(raw), str(cir)], capture_output=True, text=True, timeout=120)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0 and raw.exists(), log[-2000:]
    assert not [line for line in log.lower().splitlines() if "warning" in line or "error" in line], log[-2000:]
    volts = _read_raw(raw)
    out = np.full((g.shape[0], len(layout.pairs)), np.nan)
    for p, k, name in probes:
        out[p, k] = volts[name]
    return out


def _max_rel(a: np.ndarray, b: np.ndarray) -> float:
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    return float(np.max(np.abs(a - b) / np.abs(b)))


def test_paper_rationals_match_ngspice(paper_layout, tmp_path):
    g = np.full(paper_layout.n_channels, 1.0 / R0)
    spice = ngspice_resistance(paper_layout, g, tmp_path)[0]
    ours = equivalent_resistance(paper_layout, g)
    assert _max_rel(ours, spice) < 1e-12
    pairs = [(p.i, p.j) for p in paper_layout.pairs]
    for (i, j), ratio in {
        (1, 2): 17 / 24,
        (1, 3): 5 / 6,
        (1, 4): 29 / 24,
        (1, 5): 1.0,
        (2, 4): 5 / 4,
        (2, 6): 3 / 2,
    }.items():
        assert spice[pairs.index((i, j))] == pytest.approx(ratio * R0, rel=1e-12)


def test_each_channel_plus_50_percent_matches_ngspice(paper_layout, tmp_path):
    """Paper Fig. 3's simulation: each channel's resistance +50 % in turn."""
    n = paper_layout.n_channels
    g = np.where(np.eye(n, dtype=bool), 1.0 / (1.5 * R0), 1.0 / R0)
    assert _max_rel(equivalent_resistance(paper_layout, g), ngspice_resistance(paper_layout, g, tmp_path)) < 1e-12


def test_random_conductances_six_decades_match_ngspice(paper_layout, tmp_path):
    g = 10.0 ** np.random.default_rng(7).uniform(-7, -1, (50, paper_layout.n_channels))  # 10 ohm .. 10 Mohm
    # measured ~1e-10 (ngspice's LU on a 1e6 spread); neatskin itself is within ~1e-15 of exact here
    assert _max_rel(equivalent_resistance(paper_layout, g), ngspice_resistance(paper_layout, g, tmp_path)) < 1e-8


def test_grid_10x10_sparse_path_matches_ngspice(tmp_path):
    layout = grid_layout(10, 10, 15.0)
    assert layout.n_junctions > 64  # method="auto" takes the sparse path
    g = 10.0 ** np.random.default_rng(8).uniform(-6, -2, (4, layout.n_channels))
    spice = ngspice_resistance(layout, g, tmp_path)
    assert _max_rel(equivalent_resistance(layout, g), spice) < 1e-9  # measured ~4e-12
    assert _max_rel(equivalent_resistance(layout, g, method="dense"), spice) < 1e-9


@pytest.mark.parametrize(
    ("factor", "base", "tol"),
    [
        (1e6, 1e-6, 1e-7),  # near-short, 1 ohm in 1 Mohm: ngspice ~4e-9
        (1e12, 1e-6, 3e-2),  # near-short, 1 uohm in 1 Mohm: ngspice ~4e-3, its LU's limit, not neatskin's
        (1e-12, 1e-3, 1e-11),  # near-open, 1 Pohm in 1 kohm: ngspice ~5e-14
    ],
)
def test_stiff_single_channel_matches_ngspice(paper_layout, tmp_path, factor, base, tol):
    n = paper_layout.n_channels
    g = base * 10.0 ** np.random.default_rng(9).uniform(-1, 1, (n, n))
    g[np.arange(n), np.arange(n)] *= factor  # each channel in turn
    assert _max_rel(equivalent_resistance(paper_layout, g), ngspice_resistance(paper_layout, g, tmp_path)) < tol

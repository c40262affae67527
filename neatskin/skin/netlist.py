"""SPICE netlists of the skin's channel network for one press, with neatskin's R_eq beside them, so that the network
solver can be checked against an independent circuit simulator (ngspice, Ahkab): text in, nothing run here.

One file holds one copy of the network per electrode pair (a, b): b's junction is the ground node 0, a 1 A DC source
drives a's junction, so V(a) in volts is R_eq(a, b) in ohm. A single `.op` solves all copies at once (they share
only the ground). Every channel with a finite resistance is one resistor at the model's float written by `repr` (the
shortest decimal that reads back to the same double); an infinite one (pinched shut) is omitted, an open: SPICE has
no infinite resistor, and a 1e30 ohm stand-in has a conductance far below ngspice's pivot tolerance (1e-13 S), which
makes its matrix singular. A group of junctions that shut channels leave joined to nothing of the copy's ground gets
one LEAK_OHM resistor to ground, which ngspice's matrix needs (a floating node makes it singular). It carries no
current unless the group holds the source, so every finite R_eq is unchanged by it; where the group holds the source
the pair is cut apart (neatskin's R_eq is inf) and ngspice reads V(a) >= LEAK_OHM.

The ground of each copy is the pair's better-connected electrode (the larger sum of its channels' conductances): a
grounded Laplacian whose ground hangs on nearly shut channels is nearly singular (condition ~ the conductance
spread), and ngspice's LU then loses ~1e-3 of R_eq with two channels pinched 1e12x; grounding the other electrode
keeps the solve well conditioned (R_eq is symmetric, so either choice measures the same resistance).

After `.end` comes a `.control` block, which ngspice runs in batch mode (`ngspice -b FILE`) and other readers such
as Ahkab never see (they stop at `.end`): it prints, per pair, ngspice's R_eq, neatskin's and their relative
difference, then the largest difference, all to 17 significant digits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from neatskin.layout import Layout

LEAK_OHM = 1e9
"""The resistor from a floating group of junctions to ground: no current flows in it unless the pair is cut apart;
its conductance (1e-9 S) stays well above ngspice's pivot tolerance (1e-13 S)."""


@dataclass(frozen=True)
class PairProbe:
    """Where one pair is measured: node `node` carries V = R_eq(pair) in volts (1 A into it, `ground` grounded)."""

    label: str
    node: str
    source_junction: int
    ground_junction: int
    r_eq_ohm: float


@dataclass(frozen=True)
class Netlist:
    """A SPICE netlist (`text`) and where each pair is read (`probes`, in layout.pairs order)."""

    text: str
    probes: tuple[PairProbe, ...]


def spice_netlist(
    layout: Layout,
    channel_resistance_ohm: np.ndarray,
    pair_resistance_ohm: np.ndarray,
    title: str,
    notes: Sequence[str] = (),
) -> Netlist:
    """The netlist of one press: channel_resistance_ohm (channels,) in ohm (> 0, inf = shut), neatskin's
    pair_resistance_ohm (pairs,) in layout.pairs order; title is the first line (a comment to every reader), notes
    more comment lines after it."""
    r_ch = np.asarray(channel_resistance_ohm, dtype=float)
    r_eq = np.asarray(pair_resistance_ohm, dtype=float)
    if r_ch.shape != (layout.n_channels,) or np.any(np.isnan(r_ch)) or np.any(r_ch <= 0):
        raise ValueError(f"channel_resistance_ohm must be {layout.n_channels} resistances > 0 (inf = shut), got {r_ch}")
    if r_eq.shape != (len(layout.pairs),):
        raise ValueError(f"pair_resistance_ohm must have {len(layout.pairs)} values, got shape {r_eq.shape}")
    finite = np.isfinite(r_ch)
    with np.errstate(divide="ignore"):
        conductance = np.where(finite, 1.0 / r_ch, 0.0)
    ends = layout.channel_ends
    degree = np.bincount(ends[:, 0], conductance, layout.n_junctions) + np.bincount(
        ends[:, 1], conductance, layout.n_junctions
    )
    names = [_one_line(j.name) for j in layout.junctions]
    lines = ["* " + _one_line(t) for t in (title, *notes)] + _header(layout, r_ch, r_eq, names)
    probes = []
    for pair, r, (ia, ib) in zip(layout.pairs, r_eq.tolist(), layout.pair_electrode_index.tolist()):
        ja, jb = int(layout.electrode_junctions[ia]), int(layout.electrode_junctions[ib])
        (sa, na), (gb, nb) = (ja, pair.i), (jb, pair.j)
        if degree[jb] < degree[ja]:  # ground the better-connected electrode (module docstring)
            (sa, na), (gb, nb) = (gb, nb), (sa, na)
        tag = f"p{pair.i}_{pair.j}"
        probe = PairProbe(pair.label, f"{tag}_n{sa}", sa, gb, r)
        probes.append(probe)
        lines += _copy(layout, r_ch, tag, probe, (na, nb), names)
    lines += [".op", ".end", *_control(probes)]
    return Netlist("\n".join(lines) + "\n", tuple(probes))


def _one_line(text: str) -> str:
    """A name from the layout file inside a comment line: a line break in it would end the comment."""
    return " ".join(str(text).splitlines())


def _header(layout: Layout, r_ch: np.ndarray, r_eq: np.ndarray, names: list[str]) -> list[str]:
    lines = [
        f"* layout {_one_line(layout.name)} ({_one_line(layout.source)}): {layout.n_junctions} junctions, {layout.n_channels} channels, "
        f"{layout.n_electrodes} electrodes",
        "* One copy of the network per electrode pair (a, b): node p<a>_<b>_n<junction>; one electrode is ground",
        "* (node 0), 1 A DC flows from ground into the other, so its voltage in V is R_eq(a, b) in ohm.",
        "* Resistances are the model's doubles written by repr (the shortest decimal that reads back exactly).",
        "* A shut channel (R = inf) is left out, an open; a group of junctions it leaves joined to nothing of the",
        f"* copy's ground gets one {LEAK_OHM!r} ohm resistor to ground (R_leak), which ngspice's matrix needs (a",
        "* floating node is singular); it carries no current unless the pair is cut apart (neatskin: R_eq = inf),",
        f"* and then V >= {LEAK_OHM!r}.",
        "*",
        "* channel  junctions  R_ohm",
    ]
    for c, (channel, r) in enumerate(zip(layout.channels, r_ch.tolist())):
        state = "inf (shut: omitted)" if math.isinf(r) else repr(r)
        lines.append(f"* c{c} {_one_line(channel.name)}  {names[channel.a]} {names[channel.b]}  {state}")
    lines += ["*", "* pair  neatskin R_eq_ohm"]
    lines += [f"* {p.label} {r!r}" for p, r in zip(layout.pairs, r_eq.tolist())]
    return lines


def _copy(
    layout: Layout, r_ch: np.ndarray, tag: str, probe: PairProbe, numbers: tuple[int, int], names: list[str]
) -> list[str]:
    """One copy of the network: the pair's comment, its resistors, the leaks of its floating groups, the source."""

    def node(j: int) -> str:
        return "0" if j == probe.ground_junction else f"{tag}_n{j}"

    sa, gb = probe.source_junction, probe.ground_junction
    lines = [
        "*",
        f"* pair {probe.label}: 1 A into electrode {numbers[0]} ({names[sa]}, node {node(sa)}), electrode "
        f"{numbers[1]} ({names[gb]}) is ground; neatskin R_eq = {probe.r_eq_ohm!r} ohm",
    ]
    group = list(range(layout.n_junctions))

    def root(j: int) -> int:
        while group[j] != j:
            group[j] = group[group[j]]
            j = group[j]
        return j

    present = {sa}
    for c, ((u, v), r) in enumerate(zip(layout.channel_ends.tolist(), r_ch.tolist())):
        if math.isfinite(r):
            lines.append(f"R{tag}_c{c} {node(u)} {node(v)} {r!r}")
            group[root(u)] = root(v)
            present |= {u, v}
    floating = sorted({root(j) for j in present} - {root(gb)})
    for g in floating:
        first = sa if root(sa) == g else min(j for j in present if root(j) == g)
        members = " ".join(names[j] for j in sorted(present) if root(j) == g)
        lines.append(f"* {members}: joined to nothing of the ground through a finite channel: R_leak")
        lines.append(f"R{tag}_leak{first} {node(first)} 0 {LEAK_OHM!r}")
    lines.append(f"I{tag} 0 {node(sa)} DC 1")
    return lines


def _control(probes: Sequence[PairProbe]) -> list[str]:
    """ngspice's batch script: per pair its R_eq, neatskin's and the relative difference; then the largest one, and
    for a pair neatskin cuts apart whether ngspice found V >= LEAK_OHM (only the leak joins it)."""
    lines = [
        "* ngspice -b runs the block below (readers that stop at .end, such as Ahkab, never see it): per pair",
        "* r_<a>_<b> (ngspice's R_eq), neatskin_<a>_<b> and rel_<a>_<b> = |r / neatskin - 1|, then max_rel.",
        ".control",
        "set numdgt=17",
        "op",
        "let max_rel = 0",
        "let cut_mismatches = 0",
    ]
    for p in probes:
        name = p.label.replace("-", "_")
        lines.append(f"let r_{name} = v({p.node})")
        if math.isinf(p.r_eq_ohm):
            lines += [
                f"echo pair {p.label}: neatskin R_eq = inf (cut apart) so ngspice must read at least R_leak",  # no commas: echo drops them
                f"print r_{name}",
                f"if r_{name} < {LEAK_OHM * (1 - 1e-9)!r}",  # rounding: V is LEAK_OHM itself
                "let cut_mismatches = cut_mismatches + 1",
                f"echo MISMATCH: pair {p.label} is joined in ngspice",
                "end",
            ]
            continue
        lines += [
            f"let neatskin_{name} = {p.r_eq_ohm!r}",
            f"let rel_{name} = abs(r_{name} / neatskin_{name} - 1)",
            f"print r_{name} neatskin_{name} rel_{name}",
            f"if rel_{name} > max_rel",
            f"let max_rel = rel_{name}",
            "end",
        ]
    lines += ["print max_rel cut_mismatches", "quit", ".endc"]
    return lines

"""A study's candidates: one per (grid, pitch, channel section, probe, depth, placement strategy, electrode count),
each with a stable id (so a re-run knows what is done), and the fixed placement strategies on a grid.

Fixed strategies place electrodes on grid junctions (i, j):
- boundary: `count` junctions evenly spaced along the boundary walk, which starts at the bottom edge's middle and
  goes anticlockwise (the paper's numbering); all boundary junctions when count equals their number.
- interior: `count` junctions off the boundary, by farthest-point sampling from the one nearest the centre.
- every_k: the sub-lattice i % k == 0 and j % k == 0 plus the far edges; its size sets the count.
- explicit: the study's named lists of junction coordinates.
The optimised strategy needs the physics and lives in `evaluate.py`.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from neatskin.design.fields import grid_node
from neatskin.design.study import Study

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Candidate:
    """One layout and placement to evaluate. `nodes` is set for fixed strategies, empty for `optimised`."""

    nx: int
    ny: int
    pitch_mm: float
    channel_width_mm: float
    channel_height_mm: float
    probe_diameter_mm: float
    depth_mm: float
    strategy: str
    count: int
    placement: str
    nodes: tuple[tuple[int, int], ...]

    @property
    def candidate_id(self) -> str:
        text = json.dumps(asdict(self), sort_keys=True)
        digest = hashlib.sha256(text.encode()).hexdigest()[:8]
        return (
            f"{self.nx}x{self.ny}-{self.placement}{self.count}-d{self.probe_diameter_mm:g}-z{self.depth_mm:g}-{digest}"
        )


def boundary_walk(nx: int, ny: int) -> list[tuple[int, int]]:
    """Boundary junctions anticlockwise from the bottom edge's middle ((nx - 1) // 2, 0)."""
    ring = [(i, 0) for i in range(nx)]
    ring += [(nx - 1, j) for j in range(1, ny)]
    ring += [(i, ny - 1) for i in range(nx - 2, -1, -1)]
    ring += [(0, j) for j in range(ny - 2, 0, -1)]
    start = ring.index(((nx - 1) // 2, 0))
    return ring[start:] + ring[:start]


def boundary_nodes(nx: int, ny: int, count: int) -> tuple[tuple[int, int], ...] | None:
    ring = boundary_walk(nx, ny)
    if count > len(ring):
        return None
    picks = np.floor(np.arange(count) * len(ring) / count + 1e-9).astype(int)
    return tuple(ring[k] for k in picks)


def interior_nodes(nx: int, ny: int, count: int) -> tuple[tuple[int, int], ...] | None:
    inner = np.array([(i, j) for j in range(1, ny - 1) for i in range(1, nx - 1)], dtype=float)
    if count > len(inner):
        return None
    centre = np.array([(nx - 1) / 2, (ny - 1) / 2])
    chosen = [int(np.argmin(np.linalg.norm(inner - centre, axis=1)))]
    dist = np.linalg.norm(inner - inner[chosen[0]], axis=1)
    while len(chosen) < count:
        nxt = int(np.argmax(dist))  # first of the farthest: deterministic
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(inner - inner[nxt], axis=1))
    return tuple((int(inner[k][0]), int(inner[k][1])) for k in chosen)


def every_k_nodes(nx: int, ny: int, k: int) -> tuple[tuple[int, int], ...]:
    xs = sorted(set(range(0, nx, k)) | {nx - 1})
    ys = sorted(set(range(0, ny, k)) | {ny - 1})
    return tuple((i, j) for j in ys for i in xs)


def expand(study: Study) -> list[Candidate]:
    """Every candidate of the study, in a fixed order; infeasible combinations are skipped with a log line."""
    out: list[Candidate] = []
    for nx, ny in study.sizes:
        for pitch in study.pitch_mm:
            for width in study.channel_width_mm:
                for height in study.channel_height_mm:
                    for diameter in study.probe_diameter_mm:
                        for depth in study.depth_mm:
                            base: dict[str, Any] = dict(
                                nx=nx,
                                ny=ny,
                                pitch_mm=pitch,
                                channel_width_mm=width,
                                channel_height_mm=height,
                                probe_diameter_mm=diameter,
                                depth_mm=depth,
                            )
                            out += _placements(study, base)
    return out


def _placements(study: Study, base: dict[str, Any]) -> list[Candidate]:
    nx, ny, pitch = base["nx"], base["ny"], base["pitch_mm"]
    out: list[Candidate] = []
    for strategy in study.strategies:
        if strategy == "every_k":
            nodes = every_k_nodes(nx, ny, study.every_k)
            out.append(
                Candidate(**base, strategy=strategy, count=len(nodes), placement=f"every{study.every_k}-", nodes=nodes)
            )
            continue
        if strategy == "explicit":
            for placement in study.explicit:
                pts = tuple(grid_node(p, nx, ny, pitch) for p in placement.junctions_mm)
                nodes = tuple(n for n in pts if n is not None)
                out.append(
                    Candidate(**base, strategy=strategy, count=len(nodes), placement=placement.name, nodes=nodes)
                )
            continue
        for count in study.counts:
            if count > nx * ny:
                log.info("skipping %s %d on %d x %d: more electrodes than junctions", strategy, count, nx, ny)
                continue
            if strategy == "optimised":
                out.append(Candidate(**base, strategy=strategy, count=count, placement="optimised", nodes=()))
                continue
            found = boundary_nodes(nx, ny, count) if strategy == "boundary" else interior_nodes(nx, ny, count)
            if found is None:
                log.info("skipping %s %d on %d x %d: not enough %s junctions", strategy, count, nx, ny, strategy)
                continue
            out.append(Candidate(**base, strategy=strategy, count=count, placement=strategy, nodes=found))
    return out


OPTIMISER_MAX_CANDIDATES = 100  # the optimiser's junction pool is every junction up to this many


def optimiser_junctions(nx: int, ny: int) -> list[tuple[int, int]]:
    """Candidate junctions of the optimiser: all of them up to OPTIMISER_MAX_CANDIDATES, else the boundary plus
    the every-other-junction sub-lattice (stated in the report)."""
    if nx * ny <= OPTIMISER_MAX_CANDIDATES:
        return [(i, j) for j in range(ny) for i in range(nx)]
    nodes = dict.fromkeys(boundary_walk(nx, ny))
    nodes.update(dict.fromkeys(every_k_nodes(nx, ny, 2)))
    return sorted(nodes, key=lambda n: (n[1], n[0]))

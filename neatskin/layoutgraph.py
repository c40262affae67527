"""A skin's channel network as a planar graph: its parts and what their coordinates imply.

The parts (junctions, channels, electrodes, unordered electrode pairs) are plain frozen values;
from the junction coordinates and channel ends follow the bounded faces of the straight-line
embedding (the 'quadrants' between channels), the layout's isometries as electrode permutations,
and the classes of electrode pairs under them. `neatskin.layout.Layout` holds the parts, validates
them as a whole and caches these as its properties (and re-exports the parts: callers import them
from `neatskin.layout`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

GEOMETRY_TOL_MM = 1e-6


@dataclass(frozen=True)
class Junction:
    name: str
    x_mm: float
    y_mm: float


@dataclass(frozen=True)
class Channel:
    """A straight fluid channel between two junctions (indices into Layout.junctions)."""

    name: str
    a: int
    b: int
    length_mm: float
    width_mm: float
    height_mm: float

    @property
    def area_mm2(self) -> float:
        return self.width_mm * self.height_mm


@dataclass(frozen=True)
class Electrode:
    number: int
    junction: int


@dataclass(frozen=True, order=True)
class ElectrodePair:
    """An unordered electrode pair (i < j), by electrode number."""

    i: int
    j: int

    def __post_init__(self) -> None:
        if not self.i < self.j:
            raise ValueError(f"an electrode pair needs i < j, got ({self.i}, {self.j})")

    @property
    def label(self) -> str:
        return f"{self.i}-{self.j}"

    def __str__(self) -> str:
        return f"({self.i},{self.j})"


def bounded_faces(xy: np.ndarray, ends: np.ndarray) -> tuple[tuple[int, ...], ...]:
    """Trace the faces of a straight-line planar embedding; keep those with positive (CCW) area."""
    neighbours: dict[int, list[int]] = {}
    for a, b in ends:
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    for u, nbrs in neighbours.items():
        nbrs.sort(key=lambda v: math.atan2(xy[v, 1] - xy[u, 1], xy[v, 0] - xy[u, 0]))
    visited: set[tuple[int, int]] = set()
    faces = []
    for a, b in ends:
        for start in ((int(a), int(b)), (int(b), int(a))):
            if start in visited:
                continue
            cycle = []
            u, v = start
            while (u, v) not in visited:
                visited.add((u, v))
                cycle.append(u)
                nbrs = neighbours[v]
                # next edge: the neighbour of v just clockwise of u (previous in CCW order)
                w = nbrs[(nbrs.index(u) - 1) % len(nbrs)]
                u, v = v, w
            pts = xy[cycle]
            area = 0.5 * float(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))
            if area > GEOMETRY_TOL_MM:
                faces.append(tuple(cycle))
    return tuple(sorted(faces, key=lambda f: (float(xy[list(f), 1].mean()), float(xy[list(f), 0].mean()))))


def symmetries(
    xy: np.ndarray, channels: Sequence[Channel], electrodes: Sequence[Electrode]
) -> tuple[dict[int, int], ...]:
    """Isometries of the network (rotations and reflections about the junction centroid) that map channels onto
    channels of the same size and electrodes onto electrodes, each as electrode number -> electrode number;
    the identity first."""
    centre = xy.mean(axis=0)
    rel = xy - centre
    radius = np.hypot(rel[:, 0], rel[:, 1])
    angle = np.arctan2(rel[:, 1], rel[:, 0])
    scale = max(float(radius.max()), 1.0)
    tol = 1e-6 * scale
    # candidate transforms: map the farthest junction onto every junction at the same radius
    ref = int(np.argmax(radius))
    candidates = []
    for k in np.flatnonzero(np.abs(radius - radius[ref]) < tol):
        theta = angle[k] - angle[ref]
        c, s = math.cos(theta), math.sin(theta)
        candidates.append(np.array([[c, -s], [s, c]]))
        phi = angle[k] + angle[ref]  # reflection about the line at angle phi/2
        c2, s2 = math.cos(phi), math.sin(phi)
        candidates.append(np.array([[c2, s2], [s2, -c2]]))
    channel_keys = {
        frozenset((ch.a, ch.b)): (round(ch.width_mm, 9), round(ch.height_mm, 9), round(ch.length_mm, 9))
        for ch in channels
    }
    electrode_of = {e.junction: e.number for e in electrodes}
    found: list[dict[int, int]] = []
    for matrix in candidates:
        mapped = rel @ matrix.T
        dist = np.linalg.norm(mapped[:, None, :] - rel[None, :, :], axis=2)
        image = dist.argmin(axis=1)
        if np.any(dist[np.arange(len(rel)), image] > tol) or len(set(image.tolist())) != len(rel):
            continue
        ok = all(
            channel_keys.get(frozenset((int(image[a]), int(image[b])))) == props
            for (a, b), props in ((tuple(k), v) for k, v in channel_keys.items())
        )
        if not ok:
            continue
        if any(int(image[j]) not in electrode_of for j in electrode_of):
            continue
        perm = {num: electrode_of[int(image[j])] for j, num in electrode_of.items()}
        if perm not in found:
            found.append(perm)
    identity = {e.number: e.number for e in electrodes}
    found = [identity] + [p for p in found if p != identity]
    return tuple(found)


def pair_classes(
    pairs: Sequence[ElectrodePair], permutations: Sequence[dict[int, int]]
) -> tuple[tuple[ElectrodePair, ...], ...]:
    """Orbits of the pairs under the permutations (a layout's symmetries); each class sorted, classes in the order of their first pair."""
    seen: set[ElectrodePair] = set()
    classes = []
    for pair in pairs:
        if pair in seen:
            continue
        orbit = set()
        for sym in permutations:
            a, b = sorted((sym[pair.i], sym[pair.j]))
            orbit.add(ElectrodePair(a, b))
        seen |= orbit
        classes.append(tuple(sorted(orbit)))
    return tuple(classes)

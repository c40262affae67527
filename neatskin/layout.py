"""The skin layout value type: a channel network validated as a whole, its derived arrays, and reading it from TOML.

A layout is a frozen value loaded from TOML (see protocols/skins/paper.toml) and validated
at construction: an invalid layout cannot exist in memory. Nothing here knows that the
paper's skin has 8 electrodes or 12 channels; pairs, faces (the quadrants between channels)
and symmetry classes are all derived from the data (the parts and the planar-graph geometry
behind faces and symmetries are `neatskin.layoutgraph`'s).

Every component takes a Layout as an argument; it is the shared value type of the toolkit.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from neatskin import layoutgraph
from neatskin.config.files import ChannelDefaultsTable, LayoutFile, SkinTable
from neatskin.errors import ConfigError, Problem
from neatskin.layoutgraph import Channel, Electrode, ElectrodePair, Junction  # re-exported: callers import them here

__all__ = ["Channel", "Electrode", "ElectrodePair", "Junction", "Layout", "layout_from_dict", "load_layout"]


@dataclass(frozen=True)
class Layout:
    """A channel network: junctions in the skin plane, channels between them, electrodes on junctions.

    Coordinates are in mm in the sensor frame. `resistivity_ohm_m` is the fluid's; channel
    resistances follow Pouillet's law R = rho * L / A.
    """

    name: str
    junctions: tuple[Junction, ...]
    channels: tuple[Channel, ...]
    electrodes: tuple[Electrode, ...]
    resistivity_ohm_m: float
    thickness_mm: float
    channel_depth_mm: float
    source: str = "<memory>"
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        problems = _validate(self)
        if problems:
            raise ConfigError(problems=problems)

    # ---- derived structure -------------------------------------------------------------

    @property
    def n_junctions(self) -> int:
        return len(self.junctions)

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def n_electrodes(self) -> int:
        return len(self.electrodes)

    @cached_property
    def xy_mm(self) -> np.ndarray:
        """Junction coordinates, shape (junctions, 2)."""
        return np.array([(j.x_mm, j.y_mm) for j in self.junctions], dtype=float)

    @cached_property
    def channel_ends(self) -> np.ndarray:
        """Junction indices of each channel's ends, shape (channels, 2)."""
        return np.array([(c.a, c.b) for c in self.channels], dtype=np.intp)

    @cached_property
    def electrode_junctions(self) -> np.ndarray:
        """Junction index of each electrode, in Layout.electrodes order, shape (electrodes,)."""
        return np.array([e.junction for e in self.electrodes], dtype=np.intp)

    @cached_property
    def electrode_index(self) -> dict[int, int]:
        """Electrode number -> position in Layout.electrodes."""
        return {e.number: k for k, e in enumerate(self.electrodes)}

    @cached_property
    def pairs(self) -> tuple[ElectrodePair, ...]:
        """S: every unordered electrode pair, sorted by (i, j)."""
        numbers = sorted(e.number for e in self.electrodes)
        return tuple(ElectrodePair(i, j) for i, j in itertools.combinations(numbers, 2))

    @cached_property
    def pair_electrode_index(self) -> np.ndarray:
        """For each pair of S, the positions of its two electrodes in Layout.electrodes, (pairs, 2)."""
        idx = self.electrode_index
        return np.array([(idx[p.i], idx[p.j]) for p in self.pairs], dtype=np.intp)

    @cached_property
    def channel_resistance_ohm(self) -> np.ndarray:
        """Pouillet resistance of each undeformed channel, R = rho L / A, shape (channels,)."""
        length_m = np.array([c.length_mm for c in self.channels]) * 1e-3
        area_m2 = np.array([c.area_mm2 for c in self.channels]) * 1e-6
        return self.resistivity_ohm_m * length_m / area_m2

    def distance_to_channels_mm(self, xy_mm: np.ndarray) -> np.ndarray:
        """(points, 2) -> (points, channels): distance from each point to each channel's centre-line segment."""
        pts = np.asarray(xy_mm, dtype=float).reshape(-1, 2)
        a = self.xy_mm[self.channel_ends[:, 0]]
        b = self.xy_mm[self.channel_ends[:, 1]]
        ab = b - a
        t = np.einsum("pcj,cj->pc", pts[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=1)
        closest = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
        return np.linalg.norm(pts[:, None, :] - closest, axis=2)

    @cached_property
    def bounds_mm(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the junctions."""
        lo, hi = self.xy_mm.min(axis=0), self.xy_mm.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @cached_property
    def faces(self) -> tuple[tuple[int, ...], ...]:
        """Bounded faces of the planar channel network (the 'quadrants'), as CCW junction cycles."""
        return layoutgraph.bounded_faces(self.xy_mm, self.channel_ends)

    @cached_property
    def symmetries(self) -> tuple[dict[int, int], ...]:
        """Isometries of the layout (rotations and reflections about the junction centroid),
        each as a map electrode number -> electrode number. The identity is first."""
        return layoutgraph.symmetries(self.xy_mm, self.channels, self.electrodes)

    @cached_property
    def pair_classes(self) -> tuple[tuple[ElectrodePair, ...], ...]:
        """Orbits of S under the layout's symmetries; each class sorted, classes by first pair."""
        return layoutgraph.pair_classes(self.pairs, self.symmetries)

    def pair_class_representatives(self) -> tuple[ElectrodePair, ...]:
        return tuple(c[0] for c in self.pair_classes)


# ---- loading -----------------------------------------------------------------------------


def load_layout(path: str | Path) -> Layout:
    """Load and validate a layout TOML file; every error names the file and the field."""
    from neatskin.tomlfile import read_toml, resolve_path

    path = resolve_path(path)
    return layout_from_dict(read_toml(path, "layout file"), source=str(path))


def layout_from_dict(data: dict, source: str = "<memory>") -> Layout:
    """Build a Layout from parsed TOML (schema: `neatskin.config.files.LayoutFile`); collects every problem."""
    from neatskin.config import parse_tables

    tables, problems = parse_tables(LayoutFile, data, source)

    def problem(field_name: str, message: str, fix: str) -> None:
        problems.append(Problem(message, source, field_name, fix))

    skin: SkinTable | None = tables.get("skin")
    defaults: ChannelDefaultsTable = tables.get("channel_defaults") or ChannelDefaultsTable()
    # a misspelt table (say [channel_default]) is one problem, not a "missing" one per channel it would fill
    # (and a misspelt [[junction]] or width key likewise: what it would have defined is not missing twice)
    unknown_table = any(p.message.startswith(("unknown table", "unknown key")) for p in problems)
    unknown_table = unknown_table or ("channel_defaults" in data and "channel_defaults" not in tables)

    junctions: list[Junction] = []
    by_name: dict[str, int] = {}
    for k, jt in enumerate(tables.get("junctions") or ()):
        if jt.name in by_name:
            problem(f"junctions[{k}].name", f"duplicate junction name '{jt.name}'", "rename one of the junctions")
            continue
        by_name[jt.name] = len(junctions)
        junctions.append(Junction(jt.name, jt.x_mm, jt.y_mm))
    known = ", ".join(by_name) or "(none defined)"
    # names are checked against the junctions only when those read cleanly: a bad or duplicate junction is
    # one problem, not one more per channel and electrode that names it
    check_refs = "junctions" in tables and len(by_name) == len(tables["junctions"]) and not unknown_table

    channels: list[Channel] = []
    seen_ends: dict[frozenset, str] = {}
    missing: dict[str, list[str]] = {"width_mm": [], "height_mm": []}
    for k, ct in enumerate(tables.get("channels") or ()):
        where = f"channels[{k}]"
        ends = []
        for key, ref in (("from", ct.start), ("to", ct.to)):
            if ref not in by_name:
                if check_refs:
                    problem(f"{where}.{key}", f"unknown junction {ref!r}", f"use one of the junction names: {known}")
            else:
                ends.append(by_name[ref])
        if len(ends) != 2:
            continue
        a, b = ends
        name = ct.name or f"{junctions[a].name}-{junctions[b].name}"
        if a == b:
            problem(where, f"channel '{name}' starts and ends at the same junction", "connect two different junctions")
            continue
        ends_key = frozenset((a, b))
        if ends_key in seen_ends:
            problem(
                where,
                f"duplicate channel: '{name}' joins the same junctions as '{seen_ends[ends_key]}'",
                "remove one of the two channels",
            )
            continue
        seen_ends[ends_key] = name
        length = ct.length_mm if ct.length_mm is not None else _distance_mm(junctions[a], junctions[b])
        width = ct.width_mm if ct.width_mm is not None else defaults.width_mm
        height = ct.height_mm if ct.height_mm is not None else defaults.height_mm
        for dim, value in (("width_mm", width), ("height_mm", height)):
            if value is None:
                missing[dim].append(where)
        if length <= 0:
            problem(f"{where}.length_mm", f"channel '{name}' has zero length", "set length_mm or move a junction")
            continue
        if width is None or height is None:
            continue
        channels.append(Channel(str(name), a, b, length, width, height))
    for dim, where_list in missing.items():
        if where_list and not unknown_table:
            problem(
                f"{where_list[0]}.{dim}" if len(where_list) == 1 else "channel_defaults",
                f"{len(where_list)} channel{'s' if len(where_list) > 1 else ''} ha{'ve' if len(where_list) > 1 else 's'}"
                f" no {dim} ({', '.join(where_list[:3])}{', ...' if len(where_list) > 3 else ''})",
                f"set {dim} in [channel_defaults], or on each channel",
            )

    electrodes: list[Electrode] = []
    used_junctions: dict[int, int] = {}
    numbers: set[int] = set()
    for k, et in enumerate(tables.get("electrodes") or ()):
        where = f"electrodes[{k}]"
        if et.number in numbers:
            problem(f"{where}.number", f"duplicate electrode number {et.number}", "give every electrode its own number")
            continue
        if et.junction not in by_name:
            if check_refs:
                problem(
                    f"{where}.junction",
                    f"electrode {et.number} is on a missing junction {et.junction!r}",
                    f"use one of the junction names: {known}",
                )
            continue
        junction = by_name[et.junction]
        if junction in used_junctions:
            problem(
                f"{where}.junction",
                f"electrodes {used_junctions[junction]} and {et.number} share junction '{et.junction}'",
                "put each electrode on its own junction",
            )
            continue
        numbers.add(et.number)
        used_junctions[junction] = et.number
        electrodes.append(Electrode(et.number, junction))

    if problems or skin is None:
        raise ConfigError(problems=problems)
    return Layout(
        name=skin.name or Path(source).stem,
        junctions=tuple(junctions),
        channels=tuple(channels),
        electrodes=tuple(sorted(electrodes, key=lambda e: e.number)),
        resistivity_ohm_m=skin.resistivity_ohm_m,
        thickness_mm=skin.thickness_mm,
        channel_depth_mm=skin.channel_depth_mm,
        source=source,
        description=skin.description,
    )


def _distance_mm(a: Junction, b: Junction) -> float:
    return math.dist((a.x_mm, a.y_mm), (b.x_mm, b.y_mm))


# ---- validation --------------------------------------------------------------------------


def _validate(layout: Layout) -> list[Problem]:
    problems: list[Problem] = []
    src = layout.source

    def problem(field_name: str, message: str, fix: str) -> None:
        problems.append(Problem(message, src, field_name, fix))

    for key in ("resistivity_ohm_m", "thickness_mm", "channel_depth_mm"):
        value = getattr(layout, key)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            problem(f"skin.{key}", f"must be a positive finite number, got {value!r}", f"set {key} > 0")
    if layout.channel_depth_mm >= layout.thickness_mm:
        problem(
            "skin.channel_depth_mm",
            f"channel depth {layout.channel_depth_mm} mm is not inside the {layout.thickness_mm} mm skin",
            "set channel_depth_mm below thickness_mm",
        )
    n = len(layout.junctions)
    names = [j.name for j in layout.junctions]
    if len(set(names)) != len(names):
        problem("junctions", "duplicate junction names", "give every junction a unique name")
    ends_seen = set()
    for k, ch in enumerate(layout.channels):
        if not (0 <= ch.a < n and 0 <= ch.b < n) or ch.a == ch.b:
            problem(f"channels[{k}]", f"channel '{ch.name}' does not join two existing junctions", "fix its ends")
            continue
        ends = frozenset((ch.a, ch.b))
        if ends in ends_seen:
            problem(f"channels[{k}]", f"duplicate channel '{ch.name}'", "remove the duplicate")
        ends_seen.add(ends)
        for attr in ("length_mm", "width_mm", "height_mm"):
            value = getattr(ch, attr)
            if not (math.isfinite(value) and value > 0):
                problem(f"channels[{k}].{attr}", f"channel '{ch.name}' has {attr} = {value!r}", f"set {attr} > 0")
    numbers = [e.number for e in layout.electrodes]
    if len(set(numbers)) != len(numbers):
        problem("electrodes", "duplicate electrode numbers", "give every electrode its own number")
    if len(numbers) < 2:
        problem("electrodes", "a layout needs at least 2 electrodes", "add electrodes")
    on_junction: dict[int, int] = {}
    for k, e in enumerate(layout.electrodes):
        if not 0 <= e.junction < n:
            problem(
                f"electrodes[{k}].junction",
                f"electrode {e.number} is on a missing junction",
                "use an existing junction",
            )
        elif e.junction in on_junction:
            problem(
                f"electrodes[{k}].junction",
                f"electrodes {on_junction[e.junction]} and {e.number} share "
                f"junction '{layout.junctions[e.junction].name}'",
                "put each electrode on its own junction",
            )
        else:
            on_junction[e.junction] = e.number
    if problems or n == 0:
        return problems
    # connectivity: every junction reachable from the first one through channels
    parent = list(range(n))

    def find(u: int) -> int:
        while parent[u] != u:
            parent[u] = parent[parent[u]]
            u = parent[u]
        return u

    for ch in layout.channels:
        parent[find(ch.a)] = find(ch.b)
    components: dict[int, list[str]] = {}
    for u in range(n):
        components.setdefault(find(u), []).append(layout.junctions[u].name)
    if len(components) > 1:
        groups = sorted(components.values(), key=len)
        problem(
            "channels",
            f"the network is disconnected: junctions {', '.join(groups[0])} are not joined to "
            f"{', '.join(groups[-1][:4])}{'...' if len(groups[-1]) > 4 else ''}",
            "add channels so every junction is reachable, or remove the stray junctions",
        )
    return problems

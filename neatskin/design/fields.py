"""The list-valued fields of a study TOML (sweeps of numbers, grid sizes, explicit placements) and where an
electrode may sit on a grid: readers that add a Problem (file, field, fix) per bad entry, never stop at the first."""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any

from neatskin.config import TableReader
from neatskin.errors import Problem


@dataclass(frozen=True)
class ExplicitPlacement:
    name: str
    junctions_mm: tuple[tuple[float, float], ...]


def as_list(reader: TableReader, key: str, default: list[Any]) -> list[Any]:
    value = reader._get(key, default)
    return value if isinstance(value, list) else [value]


def numbers(reader: TableReader, key: str, default: list[float], problems: list[Problem], source: str) -> list[float]:
    out = []
    for k, value in enumerate(as_list(reader, key, default)):
        where = f"{reader.section}.{key}[{k}]"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            problems.append(Problem(f"'{key}' needs finite numbers, got {value!r}", source, where, f"give {key} in mm"))
        elif value <= 0:
            problems.append(Problem(f"'{key}' must be positive, got {value!r}", source, where, f"set {key} > 0"))
        else:
            out.append(float(value))
    return out


def integers(
    reader: TableReader, key: str, default: list[int], problems: list[Problem], source: str, minimum: int
) -> list[int]:
    out = []
    for k, value in enumerate(as_list(reader, key, default)):
        where = f"{reader.section}.{key}[{k}]"
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            problems.append(
                Problem(
                    f"'{key}' needs whole numbers >= {minimum}, got {value!r}", source, where, f"set it >= {minimum}"
                )
            )
        else:
            out.append(value)
    return out


def choices(
    reader: TableReader, key: str, options: tuple[str, ...], default: list[str], problems: list[Problem], source: str
) -> list[str]:
    out = []
    for k, value in enumerate(as_list(reader, key, default)):
        if value in options:
            out.append(value)
            continue
        close = difflib.get_close_matches(str(value), options, n=1)
        fix = f"did you mean '{close[0]}'?" if close else f"use one of: {', '.join(options)}"
        problems.append(Problem(f"unknown {key[:-1]} {value!r}", source, f"{reader.section}.{key}[{k}]", fix))
    return out


def sizes(reader: TableReader, problems: list[Problem], source: str) -> list[tuple[int, int]]:
    out = []
    for k, value in enumerate(as_list(reader, "sizes", [[3, 3]])):
        ok = (
            isinstance(value, list)
            and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 2 for v in value)
        )
        if not ok:
            problems.append(
                Problem(
                    f"a grid size is [N, M] junctions with N, M >= 2, got {value!r}",
                    source,
                    f"layouts.sizes[{k}]",
                    "write sizes = [[5, 5], [10, 10]]",
                )
            )
        else:
            out.append((int(value[0]), int(value[1])))
    return out


def explicit(reader: TableReader, problems: list[Problem], source: str) -> list[ExplicitPlacement]:
    raw = reader._get("explicit", [])
    out: list[ExplicitPlacement] = []
    if not isinstance(raw, list):
        problems.append(
            Problem("explicit placements must be [[electrodes.explicit]] tables", source, "electrodes.explicit", "")
        )
        return out
    for k, entry in enumerate(raw):
        where = f"electrodes.explicit[{k}]"
        if not isinstance(entry, dict):
            problems.append(Problem("must be a table", source, where, "use [[electrodes.explicit]]"))
            continue
        sub = TableReader(entry, where, source, problems)
        name = sub.text("name", f"explicit{k + 1}")
        points = sub._get("junctions_mm", None)
        sub.check_unknown()
        good = isinstance(points, list) and len(points) >= 2
        good = good and all(
            isinstance(p, list)
            and len(p) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in p)
            for p in points
        )
        if not good:
            problems.append(
                Problem(
                    f"junctions_mm must list at least 2 [x_mm, y_mm] points, got {points!r}",
                    source,
                    f"{where}.junctions_mm",
                    "write junctions_mm = [[0, 0], [15, 0], ...] (mm from the bottom-left junction)",
                )
            )
            continue
        pts = tuple((float(p[0]), float(p[1])) for p in points)
        if len(set(pts)) != len(pts):
            problems.append(
                Problem("two electrodes on the same junction", source, f"{where}.junctions_mm", "list each once")
            )
            continue
        out.append(ExplicitPlacement(str(name), pts))
    return out


def grid_node(point_mm: tuple[float, float], nx: int, ny: int, pitch_mm: float) -> tuple[int, int] | None:
    """The grid junction (i, j) at a point, or None when the point is on no junction (1e-6 mm tolerance)."""
    i, j = point_mm[0] / pitch_mm, point_mm[1] / pitch_mm
    ri, rj = round(i), round(j)
    if abs(i - ri) * pitch_mm > 1e-6 or abs(j - rj) * pitch_mm > 1e-6:
        return None
    if not (0 <= ri < nx and 0 <= rj < ny):
        return None
    return int(ri), int(rj)


def check_explicit_on_grid(
    explicit: list[ExplicitPlacement],
    sizes: list[tuple[int, int]],
    pitch: list[float],
    problems: list[Problem],
    source: str,
) -> None:
    for k, placement in enumerate(explicit):
        for nx, ny in sizes:
            for p in pitch:
                for m, point in enumerate(placement.junctions_mm):
                    if grid_node(point, nx, ny, p) is None:
                        problems.append(
                            Problem(
                                f"electrode at ({point[0]:g}, {point[1]:g}) mm of placement '{placement.name}' is "
                                f"on no channel junction of the {nx} x {ny} grid at {p:g} mm pitch",
                                source,
                                f"electrodes.explicit[{k}].junctions_mm[{m}]",
                                f"put it on a junction: multiples of {p:g} mm up to "
                                f"({(nx - 1) * p:g}, {(ny - 1) * p:g})",
                            )
                        )
                        return

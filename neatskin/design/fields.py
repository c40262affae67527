"""Explicit electrode placements of a study and where an electrode may sit on a grid: a Problem (file, field, fix)
for an electrode on no junction. The study file's keys themselves are declared in neatskin.config.studyfile."""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.errors import Problem


@dataclass(frozen=True)
class ExplicitPlacement:
    name: str
    junctions_mm: tuple[tuple[float, float], ...]


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

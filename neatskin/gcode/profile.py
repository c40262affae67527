"""Printer profiles (protocols/printers/*.toml): bed, soft limits, feed and acceleration maxima, serial facts.

`load_printer_profile(path)` reads and validates a profile and reports every bad field at once
(one ConfigError naming file, field and fix). `PrinterProfile` is a frozen value; its
`calibration` maps sensor coordinates to printer coordinates (see calibration.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

from neatskin.errors import ConfigError, Problem
from neatskin.gcode.calibration import Calibration
from neatskin.tomlfile import read_toml, resolve_path


@dataclass(frozen=True)
class Axes:
    """One value per Cartesian axis."""

    x: float
    y: float
    z: float

    def __iter__(self):
        return iter((self.x, self.y, self.z))


@dataclass(frozen=True)
class PrinterProfile:
    name: str
    bed_x_mm: float
    bed_y_mm: float
    soft_min_mm: Axes
    soft_max_mm: Axes
    max_feed_mm_s: Axes
    max_accel_mm_s2: Axes
    accel_mm_s2: float
    travel_feed_mm_s: float
    z_feed_mm_s: float
    press_feed_mm_s: float
    safe_height_mm: float
    park_mm: Axes
    calibration: Calibration
    baud_rate: int = 115200
    planner_buffer_size: int = 16
    rx_buffer_size: int = 128
    homing_time_s: float = 20.0
    firmware: str = "Marlin"
    description: str = ""
    source: str = "<memory>"

    def __post_init__(self) -> None:
        problems = _check(self)
        if problems:
            raise ConfigError(problems=problems)

    def with_calibration(self, calibration: Calibration) -> PrinterProfile:
        """The same printer with a refitted calibration (checked again against the z limits)."""
        return replace(self, calibration=calibration)


def load_printer_profile(path: str | Path) -> PrinterProfile:
    """Load and validate a printer profile TOML; every problem in the file in one ConfigError."""
    path = resolve_path(path)
    return printer_profile_from_dict(read_toml(path, "printer profile"), str(path))


def printer_profile_from_dict(data: dict, source: str = "<memory>") -> PrinterProfile:
    problems: list[Problem] = []

    def table(name: str) -> dict:
        value = data.get(name)
        if not isinstance(value, dict):
            problems.append(
                Problem(
                    f"missing [{name}] table", source, name, f"add a [{name}] table (see protocols/printers/paper.toml)"
                )
            )
            return {}
        return value

    def number(tab: dict, tname: str, key: str, *, positive: bool = True, default: float | None = None) -> float:
        where = f"{tname}.{key}"
        value = tab.get(key, default)
        if value is None:
            problems.append(Problem(f"missing '{key}'", source, where, f"set {key} in [{tname}]"))
            return math.nan
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            problems.append(
                Problem(f"'{key}' must be a finite number, got {value!r}", source, where, f"set {key} to a number")
            )
            return math.nan
        if positive and value <= 0:
            problems.append(Problem(f"'{key}' must be positive, got {value!r}", source, where, f"set {key} > 0"))
            return math.nan
        return float(value)

    def integer(tab: dict, tname: str, key: str, default: int) -> int:
        value = tab.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            problems.append(
                Problem(
                    f"'{key}' must be a positive integer, got {value!r}",
                    source,
                    f"{tname}.{key}",
                    f"set {key} to a positive whole number",
                )
            )
            return 1
        return value

    printer, bed, soft = table("printer"), table("bed"), table("soft_limits")
    feed, accel, motion = table("max_feed"), table("max_accel"), table("motion")
    park, cal = data.get("park", {}), table("calibration")
    soft_min = Axes(*(number(soft, "soft_limits", f"min_{a}_mm", positive=False) for a in "xyz"))
    soft_max = Axes(*(number(soft, "soft_limits", f"max_{a}_mm", positive=False) for a in "xyz"))
    values = dict(
        name=str(printer.get("name", Path(source).stem)),
        bed_x_mm=number(bed, "bed", "size_x_mm"),
        bed_y_mm=number(bed, "bed", "size_y_mm"),
        soft_min_mm=soft_min,
        soft_max_mm=soft_max,
        max_feed_mm_s=Axes(*(number(feed, "max_feed", f"{a}_mm_s") for a in "xyz")),
        max_accel_mm_s2=Axes(*(number(accel, "max_accel", f"{a}_mm_s2") for a in "xyz")),
        accel_mm_s2=number(motion, "motion", "accel_mm_s2"),
        travel_feed_mm_s=number(motion, "motion", "travel_feed_mm_s"),
        z_feed_mm_s=number(motion, "motion", "z_feed_mm_s"),
        press_feed_mm_s=number(motion, "motion", "press_feed_mm_s"),
        safe_height_mm=number(motion, "motion", "safe_height_mm"),
        park_mm=Axes(
            *(
                number(park, "park", key, positive=False, default=default)
                if math.isfinite(default) or key in park
                else math.nan
                for key, default in (("x_mm", soft_min.x), ("y_mm", soft_max.y), ("z_mm", soft_max.z))
            )
        ),
        calibration=None,
        baud_rate=integer(printer, "printer", "baud_rate", 115200),
        planner_buffer_size=integer(printer, "printer", "planner_buffer_size", 16),
        rx_buffer_size=integer(printer, "printer", "rx_buffer_size", 128),
        homing_time_s=number(printer, "printer", "homing_time_s", default=20.0),
        firmware=str(printer.get("firmware", "Marlin")),
        description=str(printer.get("description", "")),
        source=source,
    )
    cal_values = {
        k: number(cal, "calibration", k, positive=False)
        for k in ("offset_x_mm", "offset_y_mm", "rotation_deg", "surface_z_mm")
    }
    if problems:
        # cross-field problems among the fields that are valid, so one run reports everything
        partial = SimpleNamespace(**{**values, "calibration": SimpleNamespace(**cal_values)})
        raise ConfigError(problems=problems + _check(partial))
    values["calibration"] = Calibration(**cal_values)
    return PrinterProfile(**values)


def _check(p) -> list[Problem]:
    """Cross-field checks; a comparison involving a field that failed to load (NaN) is skipped."""
    problems: list[Problem] = []

    def problem(where: str, message: str, fix: str) -> None:
        problems.append(Problem(message, p.source, where, fix))

    def known(*values: float) -> bool:
        return all(math.isfinite(v) for v in values)

    for axis in "xyz":
        lo, hi = getattr(p.soft_min_mm, axis), getattr(p.soft_max_mm, axis)
        if known(lo, hi) and not lo < hi:
            problem(
                f"soft_limits.max_{axis}_mm",
                f"soft limit max_{axis}_mm = {hi} is not above min_{axis}_mm = {lo}",
                f"set max_{axis}_mm > min_{axis}_mm",
            )
    for axis, size in (("x", p.bed_x_mm), ("y", p.bed_y_mm)):
        lo, hi = getattr(p.soft_min_mm, axis), getattr(p.soft_max_mm, axis)
        if known(lo, hi, size) and (lo < 0 or hi > size):
            problem(
                f"soft_limits.max_{axis}_mm",
                f"soft limits on {axis} [{lo}, {hi}] reach outside the {size} mm bed",
                f"keep the {axis} soft limits within 0..{size} (bed.size_{axis}_mm)",
            )
    xy_max = min(p.max_feed_mm_s.x, p.max_feed_mm_s.y)
    if known(xy_max, p.travel_feed_mm_s) and p.travel_feed_mm_s > xy_max:
        problem(
            "motion.travel_feed_mm_s",
            f"travel feed {p.travel_feed_mm_s} mm/s exceeds the x/y maximum {xy_max} mm/s",
            f"set travel_feed_mm_s <= {xy_max}",
        )
    for key in ("z_feed_mm_s", "press_feed_mm_s"):
        value = getattr(p, key)
        if known(value, p.max_feed_mm_s.z) and value > p.max_feed_mm_s.z:
            problem(
                f"motion.{key}",
                f"{key} = {value} mm/s exceeds the z maximum {p.max_feed_mm_s.z} mm/s",
                f"set {key} <= {p.max_feed_mm_s.z} (max_feed.z_mm_s)",
            )
    surface = p.calibration.surface_z_mm
    if known(p.safe_height_mm, surface, p.soft_max_mm.z) and p.safe_height_mm + surface > p.soft_max_mm.z:
        problem(
            "motion.safe_height_mm",
            f"safe height {p.safe_height_mm} mm above the surface at z = {surface} mm "
            f"is above the z soft limit {p.soft_max_mm.z} mm",
            "lower safe_height_mm or check calibration.surface_z_mm",
        )
    for axis in "xyz":
        value, lo, hi = getattr(p.park_mm, axis), getattr(p.soft_min_mm, axis), getattr(p.soft_max_mm, axis)
        if known(value, lo, hi) and not lo <= value <= hi:
            problem(
                f"park.{axis}_mm",
                f"park {axis} = {value} mm is outside the soft limits",
                f"put park.{axis}_mm inside [{lo}, {hi}]",
            )
    return problems

"""Printer profiles (protocols/printers/*.toml): bed, soft limits, feed and acceleration maxima, serial facts.

`load_printer_profile(path)` reads and validates a profile and reports every bad field at once
(one ConfigError naming file, field and fix). `PrinterProfile` is a frozen value; its
`calibration` maps sensor coordinates to printer coordinates (see calibration.py).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from types import SimpleNamespace

from neatskin.config import parse_tables
from neatskin.config.declare import source_field
from neatskin.config.printerfile import MotionTable, ParkTable, PrinterFile, PrinterTable
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


Box = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True, kw_only=True)
class PrinterProfile(PrinterTable):
    """A whole printer profile: the `[printer]` table's settings (declared once, in `PrinterTable`, and checked
    at construction) and the geometry, motion and calibration the loader gathers from the other tables."""

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
    source: str = source_field()

    def __post_init__(self) -> None:
        if self.name is None:  # the [printer] table's default: the file's stem
            object.__setattr__(self, "name", Path(self.source).stem)
        super().__post_init__()
        problems = _check(self)
        if problems:
            raise ConfigError(problems=problems)

    @property
    def printer_name(self) -> str:
        """The printer's name: `[printer] name`, or the file's stem (filled in at construction)."""
        return self.name or Path(self.source).stem

    @cached_property
    def travel_box_mm(self) -> Box:
        """(lo, hi) the head can reach, native mm: the bed in x and y (from 0), the soft limits in z. A stepper
        driven past it loses steps against the frame (the simulated printer, unhomed or with M211 S0)."""
        return (0.0, 0.0, self.soft_min_mm.z), (self.bed_x_mm, self.bed_y_mm, self.soft_max_mm.z)

    @cached_property
    def soft_box_mm(self) -> Box:
        """(lo, hi) the travel within the soft limits: where a move may go with M211 S1. One box for
        `gcode check` (bounds.check_moves) and the simulated printer's clamp of homed axes."""
        (lx, ly, lz), (hx, hy, hz) = self.travel_box_mm
        lo, hi = self.soft_min_mm, self.soft_max_mm
        return (max(lx, lo.x), max(ly, lo.y), max(lz, lo.z)), (min(hx, hi.x), min(hy, hi.y), min(hz, hi.z))

    def with_calibration(self, calibration: Calibration) -> PrinterProfile:
        """The same printer with a refitted calibration (checked again against the z limits)."""
        return replace(self, calibration=calibration)


def load_printer_profile(path: str | Path) -> PrinterProfile:
    """Load and validate a printer profile TOML; every problem in the file in one ConfigError."""
    path = resolve_path(path)
    return printer_profile_from_dict(read_toml(path, "printer profile"), str(path))


def printer_profile_from_dict(data: dict, source: str = "<memory>") -> PrinterProfile:
    """A PrinterProfile from parsed TOML (schema: `neatskin.config.printerfile.PrinterFile`); every problem at once."""
    tables, problems = parse_tables(PrinterFile, data, source)
    nan3 = Axes(math.nan, math.nan, math.nan)
    printer: PrinterTable = tables.get("printer") or PrinterTable()
    bed, soft, feed = tables.get("bed"), tables.get("soft_limits"), tables.get("max_feed")
    accel, motion, cal = tables.get("max_accel"), tables.get("motion"), tables.get("calibration")
    park: ParkTable = tables.get("park") or ParkTable()
    soft_min = Axes(soft.min_x_mm, soft.min_y_mm, soft.min_z_mm) if soft else nan3
    soft_max = Axes(soft.max_x_mm, soft.max_y_mm, soft.max_z_mm) if soft else nan3
    motion_values = (
        dataclasses.asdict(motion) if motion else {f.name: math.nan for f in dataclasses.fields(MotionTable)}
    )
    values = dict(
        name=printer.name or Path(source).stem,
        bed_x_mm=bed.size_x_mm if bed else math.nan,
        bed_y_mm=bed.size_y_mm if bed else math.nan,
        soft_min_mm=soft_min,
        soft_max_mm=soft_max,
        max_feed_mm_s=Axes(feed.x_mm_s, feed.y_mm_s, feed.z_mm_s) if feed else nan3,
        max_accel_mm_s2=Axes(accel.x_mm_s2, accel.y_mm_s2, accel.z_mm_s2) if accel else nan3,
        **motion_values,
        park_mm=Axes(  # the defaults of an absent [park]: the far corner at the top of the Z travel
            soft_min.x if park.x_mm is None else park.x_mm,
            soft_max.y if park.y_mm is None else park.y_mm,
            soft_max.z if park.z_mm is None else park.z_mm,
        ),
        **{f.name: getattr(printer, f.name) for f in dataclasses.fields(PrinterTable) if f.name != "name"},
        source=source,
    )
    nan_cal = SimpleNamespace(surface_z_mm=math.nan)
    if problems or cal is None:
        # cross-field problems among the tables that are valid, so one run reports everything
        partial = SimpleNamespace(**values, calibration=cal or nan_cal)
        raise ConfigError(problems=problems + _check(partial))
    return PrinterProfile(**values, calibration=Calibration(**dataclasses.asdict(cal)))


# The serial speeds Marlin can run at: Configuration.h's BAUDRATE list, the rates M575 accepts (M575.cpp).
MARLIN_BAUD_RATES = (2400, 9600, 19200, 38400, 57600, 115200, 250000, 500000, 1000000)


def _check(p) -> list[Problem]:
    """Cross-field checks; a comparison involving a field that failed to load (NaN) is skipped."""
    problems: list[Problem] = []

    def problem(where: str, message: str, fix: str) -> None:
        problems.append(Problem(message, p.source, where, fix))

    def known(*values: float) -> bool:
        return all(math.isfinite(v) for v in values)

    baud = p.baud_rate
    if str(p.firmware).lower() == "marlin" and isinstance(baud, int) and baud not in MARLIN_BAUD_RATES:
        nearest = min(MARLIN_BAUD_RATES, key=lambda rate: abs(rate - baud))
        problem(
            "printer.baud_rate",
            f"baud_rate = {baud} is not a speed Marlin runs at ({', '.join(map(str, MARLIN_BAUD_RATES))}): the "
            "port would open and the printer answer with garbage",
            f"set baud_rate to the BAUDRATE the printer's firmware was built with (nearest: {nearest})",
        )

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
    rotation = getattr(p.calibration, "rotation_deg", math.nan)
    if known(rotation) and rotation != 0:
        quarter = round(rotation / (math.pi / 4))
        if quarter != 0 and abs(rotation - quarter * math.pi / 4) < 5e-5:
            problem(
                "calibration.rotation_deg",
                f"rotation_deg = {rotation:g} looks like {quarter * 45:g} degrees written in radians",
                f"rotation_deg is in degrees: write {quarter * 45:.1f} (a real rotation of {rotation:g} degrees: "
                f"write {round(rotation, 3):g})",
            )
    for axis in "xyz":
        value, lo, hi = getattr(p.park_mm, axis), getattr(p.soft_min_mm, axis), getattr(p.soft_max_mm, axis)
        if known(lo, hi) and not lo < hi:
            continue  # the soft limits are reported above; the park position is not a second mistake
        if known(value, lo, hi) and not lo <= value <= hi:
            problem(
                f"park.{axis}_mm",
                f"park {axis} = {value} mm is outside the soft limits",
                f"put park.{axis}_mm inside [{lo}, {hi}]",
            )
    return problems

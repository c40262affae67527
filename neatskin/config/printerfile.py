"""The printer profile's schema (protocols/printers/*.toml): serial and firmware facts, bed, limits, motion, calibration.

Kept apart from the other file kinds (`files`) as the design study's is (`studyfile`): it describes
the printer alone, knows no protocol caps, and `neatskin.gcode.profile.PrinterProfile` extends
its `[printer]` table.
"""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.config.declare import setting
from neatskin.config.settings import Settings


@dataclass(frozen=True)
class PrinterTable(Settings):
    """The printer's serial and firmware facts (`neatskin.gcode.profile.PrinterProfile` derives from it)."""

    TOML_TABLE = "printer"
    name: str | None = setting(None, max_len=200, default_doc="the file's stem", doc="printer name")
    description: str = setting("", allow_empty=True, doc="free text")
    firmware: str = setting("Marlin", max_len=64, doc="firmware family")
    baud_rate: int = setting(
        115_200,
        gt=0,
        le=10_000_000,
        doc="serial speed; with firmware Marlin one of the rates Marlin runs at (2400, 9600, 19200, 38400, 57600,"
        " 115200, 250000, 500000, 1000000: Configuration.h's BAUDRATE list, M575's), else refused with the nearest",
    )
    planner_buffer_size: int = setting(16, gt=0, le=10_000, doc="BLOCK_BUFFER_SIZE: moves queued ahead")
    rx_buffer_size: int = setting(128, gt=0, le=1_000_000, doc="RX_BUFFER_SIZE: bytes of serial input")
    homing_time_s: float = setting(20.0, unit="s", gt=0, le=3_600, doc="G28 of all axes, worst case")
    z_clearance_for_homing_mm: float = setting(
        5.0,
        unit="mm",
        ge=0,
        le=10_000,
        doc="Z_CLEARANCE_FOR_HOMING: G28 raises Z by this before homing X or Y (to it once Z is homed; 0: no raise);"
        " stock Marlin 5 (Z_CLEARANCE_BETWEEN_PROBES, Conditionals_post.h). The campaign's preamble does not rely on"
        " it: its `G28 R<surface_z_mm + safe_height_mm>` raises Z by that much first, homed or not",
    )
    z_after_homing_mm: float | None = setting(
        None,
        unit="mm",
        ge=0,
        le=10_000,
        default_doc="z_clearance_for_homing_mm",
        doc="Z_AFTER_HOMING: where G28 leaves Z once Z is homed; stock Marlin leaves it undefined, so motion.h's"
        " Z_POST_CLEARANCE is the homing clearance",
    )
    z_homing_feed_mm_s: float = setting(
        4.0, unit="mm/s", gt=0, le=10_000, doc="HOMING_FEEDRATE_MM_M's Z: G28's Z moves; stock Marlin 4*60 mm/min"
    )
    stepper_timeout_s: float = setting(
        120.0,
        unit="s",
        ge=0,
        le=86_400,
        doc="DEFAULT_STEPPER_DEACTIVE_TIME: idle steppers go off after this (0: never); a longer pause re-homes",
    )


@dataclass(frozen=True)
class BedTable(Settings):
    size_x_mm: float = setting(unit="mm", gt=0, le=10_000, doc="bed size")
    size_y_mm: float = setting(unit="mm", gt=0, le=10_000, doc="bed size")


@dataclass(frozen=True)
class SoftLimitsTable(Settings):
    min_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    min_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    min_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")


@dataclass(frozen=True)
class MaxFeedTable(Settings):
    x_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")
    y_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")
    z_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")


@dataclass(frozen=True)
class MaxAccelTable(Settings):
    x_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")
    y_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")
    z_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")


@dataclass(frozen=True)
class MotionTable(Settings):
    accel_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="M204 acceleration")
    travel_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="xy travel at the safe height")
    z_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="lifting and descending to contact")
    press_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="from contact on to the press depth")
    safe_height_mm: float = setting(unit="mm", gt=0, le=10_000, doc="probe tip above the skin while travelling")


@dataclass(frozen=True)
class ParkTable(Settings):
    x_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.min_x_mm",
        doc="where the probe waits after the campaign, printer frame",
    )
    y_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.max_y_mm",
        doc="where the probe waits after the campaign, printer frame",
    )
    z_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.max_z_mm",
        doc="where the probe waits after the campaign, printer frame; never below calibration.surface_z_mm +"
        " motion.safe_height_mm (the program parks at the higher of the two; campaign check warns of a lower one)",
    )


@dataclass(frozen=True)
class CalibrationTable(Settings):
    offset_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer xy of the sensor's origin")
    offset_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer xy of the sensor's origin")
    rotation_deg: float = setting(
        unit="deg", ge=-360, le=360, doc="sensor frame against the printer's, in degrees (a radian value is refused)"
    )
    surface_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer z touching the skin surface")


@dataclass(frozen=True)
class PrinterFile(Settings):
    """A printer profile (protocols/printers/paper.toml)."""

    printer: PrinterTable
    bed: BedTable
    soft_limits: SoftLimitsTable
    max_feed: MaxFeedTable
    max_accel: MaxAccelTable
    motion: MotionTable
    calibration: CalibrationTable
    park: ParkTable = ParkTable()

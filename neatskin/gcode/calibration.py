"""Sensor-to-printer coordinates: the rigid transform (offset, rotation, surface height) and its fit.

printer_xy = R(rotation_deg) @ sensor_xy + (offset_x_mm, offset_y_mm); the skin's top surface
sits at printer Z = surface_z_mm. `fit_calibration` recovers the transform from two or three
reference points a technician jogged the probe onto (sensor xy -> printer xyz) by a least-squares
rigid fit (2-D Kabsch, no scale), and reports the residual of every point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neatskin.errors import ConfigError


@dataclass(frozen=True)
class Calibration:
    offset_x_mm: float = 0.0
    offset_y_mm: float = 0.0
    rotation_deg: float = 0.0
    surface_z_mm: float = 0.0

    def __post_init__(self) -> None:
        for name in ("offset_x_mm", "offset_y_mm", "rotation_deg", "surface_z_mm"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(
                    f"{name} must be a finite number, got {value!r}",
                    field=f"calibration.{name}",
                    fix=f"set {name} in the printer profile's [calibration]",
                )

    @property
    def matrix(self) -> np.ndarray:
        theta = math.radians(self.rotation_deg)
        c, s = math.cos(theta), math.sin(theta)
        return np.array([[c, -s], [s, c]])

    def to_printer(self, x_mm, y_mm) -> tuple[np.ndarray, np.ndarray]:
        """Sensor-frame xy (scalars or arrays) -> printer-frame xy, same shape."""
        x = np.asarray(x_mm, dtype=float)
        y = np.asarray(y_mm, dtype=float)
        m = self.matrix
        return m[0, 0] * x + m[0, 1] * y + self.offset_x_mm, m[1, 0] * x + m[1, 1] * y + self.offset_y_mm

    def to_sensor(self, x_mm, y_mm) -> tuple[np.ndarray, np.ndarray]:
        """Printer-frame xy -> sensor-frame xy (the inverse of to_printer)."""
        x = np.asarray(x_mm, dtype=float) - self.offset_x_mm
        y = np.asarray(y_mm, dtype=float) - self.offset_y_mm
        m = self.matrix
        return m[0, 0] * x + m[1, 0] * y, m[0, 1] * x + m[1, 1] * y


@dataclass(frozen=True)
class CalibrationFit:
    """A fitted calibration and how well it explains the reference points."""

    calibration: Calibration
    residual_mm: tuple[float, ...]  # xy distance of each point from its fitted image
    z_residual_mm: tuple[float, ...]  # each point's z minus the fitted surface height

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residual_mm))))

    @property
    def max_mm(self) -> float:
        return float(np.max(self.residual_mm))

    @property
    def z_spread_mm(self) -> float:
        """Largest |z residual|: the skin's tilt or unevenness across the reference points."""
        return float(np.max(np.abs(self.z_residual_mm)))


def fit_calibration(sensor_xy_mm, printer_xyz_mm, source: str = "<calibration>") -> CalibrationFit:
    """Fit offset, rotation and surface height from 2+ reference points.

    sensor_xy_mm: (points, 2) where the probe was in the sensor frame; printer_xyz_mm: (points, 3)
    the printer position (M114) with the probe just touching the skin there.
    """
    sensor = np.asarray(sensor_xy_mm, dtype=float)
    printer = np.asarray(printer_xyz_mm, dtype=float)
    if (
        sensor.ndim != 2
        or sensor.shape[1] != 2
        or printer.ndim != 2
        or printer.shape[1] != 3
        or len(sensor) != len(printer)
    ):
        raise ConfigError(
            f"need (points, 2) sensor xy and (points, 3) printer xyz, got {sensor.shape} and {printer.shape}",
            file=source,
            field="reference_points",
            fix="give one printer x, y, z per sensor x, y",
        )
    if len(sensor) < 2 or not (np.all(np.isfinite(sensor)) and np.all(np.isfinite(printer))):
        raise ConfigError(
            "need at least 2 finite reference points",
            file=source,
            field="reference_points",
            fix="jog the probe onto two or three distinct marks (e.g. electrode junctions)",
        )
    centred = sensor - sensor.mean(axis=0)
    if float(np.max(np.linalg.norm(centred, axis=1))) < 1.0:
        raise ConfigError(
            "reference points are less than 1 mm apart; rotation is undetermined",
            file=source,
            field="reference_points",
            fix="use reference points far apart, e.g. opposite corners",
        )
    target = printer[:, :2] - printer[:, :2].mean(axis=0)
    # 2-D Kabsch: the rotation angle maximising sum of target . R sensor
    cross = float(np.sum(centred[:, 0] * target[:, 1] - centred[:, 1] * target[:, 0]))
    dot = float(np.sum(centred[:, 0] * target[:, 0] + centred[:, 1] * target[:, 1]))
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    rotated_mean = np.array([[c, -s], [s, c]]) @ sensor.mean(axis=0)
    offset = printer[:, :2].mean(axis=0) - rotated_mean
    surface_z = float(printer[:, 2].mean())
    cal = Calibration(float(offset[0]), float(offset[1]), math.degrees(theta), surface_z)
    px, py = cal.to_printer(sensor[:, 0], sensor[:, 1])
    residual = np.hypot(px - printer[:, 0], py - printer[:, 1])
    return CalibrationFit(cal, tuple(float(r) for r in residual), tuple(float(z - surface_z) for z in printer[:, 2]))

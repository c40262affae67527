"""The finite-element press's set-up as values: the geometry of one channel across the skin, the silicone, the
solver's settings, and the closure threshold; light to import (numpy only), so the skin model can key and read a
pinch kernel without loading the solver (skin/mechanics.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass

SHUT_AREA_RATIO = 0.02  # a section this pinched is counted shut (its corners' slivers carry no current worth having)
CLOSING_AREA_RATIO = 0.15  # Newton failing below this means the walls are folding into each other: shut


@dataclass(frozen=True)
class PressGeometry:
    """One channel across a skin on a rigid table, and the flat probe (plane strain: a strip of width 2a)."""

    thickness_mm: float = 5.5
    channel_width_mm: float = 2.0
    channel_height_mm: float = 1.0
    channel_depth_mm: float = 2.0  # channel centre line below the pressed surface
    probe_radius_mm: float = 2.75
    half_width_mm: float = 25.0  # the modelled skin spans |x| <= this; rollers (u_x = 0) at its ends

    def __post_init__(self) -> None:
        for name in ("thickness_mm", "channel_width_mm", "channel_height_mm", "channel_depth_mm", "probe_radius_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        roof = self.channel_depth_mm - self.channel_height_mm / 2
        floor = self.thickness_mm - self.channel_depth_mm - self.channel_height_mm / 2
        if roof <= 0 or floor <= 0:
            raise ValueError(
                f"the channel ({self.channel_height_mm} mm high, centre {self.channel_depth_mm} mm deep) must lie "
                f"inside the {self.thickness_mm} mm skin"
            )
        if self.half_width_mm < 3 * self.thickness_mm + self.channel_width_mm:
            raise ValueError(f"half_width_mm must be at least 3 skin thicknesses, got {self.half_width_mm!r}")

    @property
    def channel_floor_mm(self) -> float:
        """Height of the channel's floor above the table."""
        return self.thickness_mm - self.channel_depth_mm - self.channel_height_mm / 2

    @property
    def channel_roof_mm(self) -> float:
        return self.channel_floor_mm + self.channel_height_mm


@dataclass(frozen=True)
class Material:
    """Nearly incompressible neo-Hookean silicone. EcoFlex 00-30: mu = 0.023 MPa (docs/skin.md, sourced)."""

    shear_modulus_mpa: float = 0.023
    bulk_ratio: float = 1000.0  # K / mu; 1000 is Poisson's ratio 0.4995

    def __post_init__(self) -> None:
        if not (math.isfinite(self.shear_modulus_mpa) and self.shear_modulus_mpa > 0):
            raise ValueError(f"shear_modulus_mpa must be a positive number, got {self.shear_modulus_mpa!r}")
        if not (math.isfinite(self.bulk_ratio) and self.bulk_ratio >= 10):
            raise ValueError(f"bulk_ratio must be >= 10 (nearly incompressible), got {self.bulk_ratio!r}")


@dataclass(frozen=True)
class SolverSettings:
    """Mesh size and Newton controls. element_mm is the edge near the channel and the probe; it doubles away."""

    element_mm: float = 0.25
    depth_step_mm: float = 0.25
    max_depth_mm: float = 4.5
    newton_tol: float = 1e-7  # on the free residual, relative to the probe's reaction
    max_newton: int = 25
    max_halvings: int = 6
    contact_penalty_ratio: float = 1e5  # contact spring per node over mu (mm)
    probe_edge_radius_mm: float = 0.5  # the probe's rim, rounded (a knife edge crushes the corner element)

    def __post_init__(self) -> None:
        for name in ("element_mm", "depth_step_mm", "max_depth_mm", "newton_tol", "contact_penalty_ratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")

"""What the simulated Marlin reports of where it is: M114's line (32-bit floats printed as Marlin prints them, steps
as its planner rounds them) and the extruder's E, which Marlin tracks although the probe rig has no extruder.

E follows G1/G0's E word in absolute or relative mode (M82/M83, which G90/G91 override again: Marlin's
set_relative_mode) and G92 E; the heaters stay at the room's temperature, below EXTRUDE_MINTEMP (170 C), so every
E change of at least a step is refused by the planner with `echo: cold extrusion prevented` while E still moves
(planner.cpp, PREVENT_COLD_EXTRUSION; the native build: `G1 X5 E1` says so, then M114 reports E:1.00).
"""

from __future__ import annotations

from collections.abc import Sequence

from neatskin.sim.settings import f32, lround32, marlin_float

COLD_EXTRUSION = "echo: cold extrusion prevented"


class Extruder:
    """E as M114 reports it (current_position.e) and the mode it moves in."""

    def __init__(self) -> None:
        self.e_mm = 0.0
        self.e_relative: bool | None = None  # M82 (False) / M83 (True) since the last G90/G91; None: as G90/G91
        self.relative = False  # G91

    def mode(self, code: str) -> None:
        """G90/G91/M82/M83."""
        if code in ("G90", "G91"):
            self.relative, self.e_relative = code == "G91", None
        elif code in ("M82", "M83"):
            self.e_relative = code == "M83"

    def set_position(self, e_mm: float) -> None:
        """G92 E: set directly (no workspace offset for E)."""
        self.e_mm = f32(e_mm)

    def move(self, e: float, steps_per_mm: float) -> bool:
        """A move's E word; True when the planner would have stepped E (and so says cold extrusion prevented)."""
        relative = self.relative if self.e_relative is None else self.e_relative
        old = self.e_mm
        self.e_mm = f32(old + f32(e)) if relative else f32(e)
        return lround32(self.e_mm, steps_per_mm) != lround32(old, steps_per_mm)


def position_report(
    native_mm: Sequence[float | None], offset_mm: Sequence[float], e_mm: float, steps_per_mm: Sequence[float]
) -> str:
    """M114's line: the planner's position (zeros where unknown) plus the workspace offset, as 32-bit floats printed
    by printFloat (52.345 -> 52.35), then the step counts (lroundf of the native position times steps per mm)."""
    native = [f32(p) if p is not None else 0.0 for p in native_mm]
    x, y, z = (f32(p + f32(o)) for p, o in zip(native, offset_mm))
    cx, cy, cz = (lround32(p, s) for p, s in zip(native, steps_per_mm))
    m = marlin_float
    return f"X:{m(x)} Y:{m(y)} Z:{m(z)} E:{m(e_mm)} Count X:{cx} Y:{cy} Z:{cz}"

"""Press programs: presses as structured blocks of named phases, ready for the campaign runner or a file.

A press is four phases, each starting with an `M118 E1 NS press=<id> phase=<name>` marker
(the printer echoes `echo:NS press=<id> phase=<name>`) and ending in `M400`:
  travel  (to the safe height, then over the target)     acquire="baseline"
  descend (down to contact with the skin's surface)
  press   (on to depth_mm below the surface, press feed)  acquire="pressed"
  lift    (back to the safe height)
With `hold_in_gcode=True` (a file for standalone streaming) the press phase holds with
`G4 P<ms>` before its final M400; for the runner the acquisition itself is the hold.
Everything is checked by bounds.check_press_plan before any line is formatted. The program holds
its presses as numbers and formats each block's lines when it is asked for (gcode.blocks), so its
memory does not grow with the G-code text of a large campaign. `PressSpec`, the `[press]` table, is declared
(and validated at construction) in `neatskin.config.files`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from neatskin.config.files import PressSpec
from neatskin.errors import ConfigError
from neatskin.gcode import emit
from neatskin.gcode.blocks import Phase, PressBlock, PressBlocks, PressTemplate
from neatskin.gcode.bounds import check_press_plan
from neatskin.gcode.calibration import Calibration
from neatskin.gcode.ordering import press_order, route_length_mm, shorten_route
from neatskin.gcode.positions import PositionSet
from neatskin.gcode.profile import PrinterProfile
from neatskin.layout import Layout

__all__ = ["PHASES", "Phase", "PressBlock", "PressBlocks", "PressProgram", "PressSpec", "build_program"]

PHASES = emit.PHASES


@dataclass(frozen=True)
class PressProgram:
    name: str
    seed: int
    layout_name: str
    printer_name: str
    depth_mm: float
    hold_s: float
    hold_in_gcode: bool
    calibration: Calibration
    positions: PositionSet
    presses: PressBlocks  # each block's G-code is formatted when it is asked for (gcode.blocks)
    preamble: tuple[str, ...]
    postamble: tuple[str, ...]
    route_mm: float  # xy route between positions, from the first to the last
    route_unordered_mm: float | None = None  # the same without travel ordering (None: ordering off)

    def command_lines(self) -> Iterator[str]:
        """Every command in execution order (no comments)."""
        yield from self.preamble
        for block in self.presses:
            for phase in block.phases:
                yield from phase.lines
        yield from self.postamble

    def text(self) -> str:
        return emit.program_text(self)


def _check_probe_fits(layout: Layout, press: PressSpec) -> None:
    """A probe wider than the skin presses every channel at once: a unit slip (55 for 5.5), not a campaign."""
    x_min, y_min, x_max, y_max = layout.bounds_mm
    spans = [s for s in (x_max - x_min, y_max - y_min) if s > 0]
    if spans and press.probe_diameter_mm > min(spans):
        raise ConfigError(
            f"a {press.probe_diameter_mm:g} mm probe is wider than the skin "
            f"({x_max - x_min:g} x {y_max - y_min:g} mm between its outer junctions)",
            file=press.source,
            field="press.probe_diameter_mm",
            fix=f"probe_diameter_mm is the flat probe's diameter in mm (the paper's is 5.5): set it below {min(spans):g}",
        )


def build_program(
    layout: Layout,
    positions: PositionSet,
    press: PressSpec,
    profile: PrinterProfile,
    *,
    name: str = "campaign",
    seed: int = 0,
    hold_in_gcode: bool = False,
    source: str = "<program>",
) -> PressProgram:
    """The press program for these positions; every limit checked before any text is formatted."""
    emit.safe_text(name, "campaign.name", source)
    emit.safe_text(layout.name, "skin.name", layout.source)
    emit.safe_text(profile.printer_name, "printer.name", profile.source)
    _check_probe_fits(layout, press)
    cal = profile.calibration
    xy = positions.xy_mm
    route_unordered = None
    sequence = np.arange(len(positions))
    if press.travel_ordering and len(positions) > 2:
        start = np.array(cal.to_sensor(profile.park_mm.x, profile.park_mm.y), dtype=float)
        route_unordered = route_length_mm(xy, sequence)
        sequence = shorten_route(xy, start_xy_mm=start)
    order = press_order(len(positions), press.repeats, press.order, seed, sequence)
    pos_ids, repeats = order[:, 0], order[:, 1]
    px, py = cal.to_printer(xy[pos_ids, 0], xy[pos_ids, 1]) if len(order) else (np.zeros(0), np.zeros(0))
    press_ids = np.arange(len(order))
    check_press_plan(
        profile, px, py, press_ids, pos_ids, press.depth_mm, layout.thickness_mm, press.depth_margin_mm, source
    )
    route = route_length_mm(xy, pos_ids[np.r_[True, np.diff(pos_ids) != 0]]) if len(order) else 0.0

    z_safe = emit.fmt(cal.surface_z_mm + profile.safe_height_mm)
    z_press_mm = cal.surface_z_mm - press.depth_mm
    f_z, f_travel, f_press = (
        emit.feed(profile.z_feed_mm_s),
        emit.feed(profile.travel_feed_mm_s),
        emit.feed(profile.press_feed_mm_s),
    )
    template = PressTemplate(
        safe_line=f"G0 Z{z_safe} F{f_z}",
        contact_line=f"G1 Z{emit.fmt(cal.surface_z_mm)} F{f_z}",
        press_line=f"G1 Z{emit.fmt(z_press_mm)} F{f_press}",
        hold_lines=(f"G4 P{int(round(press.hold_s * 1000))}",) if hold_in_gcode and press.hold_s > 0 else (),
        travel_feed=f_travel,
        z_press_mm=z_press_mm,
    )
    blocks = PressBlocks(template, positions, pos_ids, repeats, px, py)
    park = profile.park_mm
    postamble = (
        f"G0 Z{z_safe} F{f_z}",
        f"G0 X{emit.fmt(park.x)} Y{emit.fmt(park.y)} F{f_travel}",
        f"G0 Z{emit.fmt(park_z_mm(profile))} F{f_z}",
        "M400",
        f"{emit.MARKER} program=done",
    )
    return PressProgram(
        name,
        seed,
        layout.name,
        profile.printer_name,
        press.depth_mm,
        press.hold_s,
        hold_in_gcode,
        cal,
        positions,
        blocks,
        emit.preamble_lines(cal.surface_z_mm + profile.safe_height_mm),
        postamble,
        route,
        route_unordered,
    )


def park_z_mm(profile: PrinterProfile) -> float:
    """Where the probe parks in Z: the profile's [park] z_mm, never below the travel height (surface + safe height),
    so that a low park cannot leave the probe in the skin or on the fittings."""
    return max(profile.park_mm.z, profile.calibration.surface_z_mm + profile.safe_height_mm)


def low_park_warning(profile: PrinterProfile) -> str | None:
    """One line for `campaign check` when [park] z_mm is below the travel height (the program parks higher)."""
    floor = profile.calibration.surface_z_mm + profile.safe_height_mm
    if profile.park_mm.z >= floor:
        return None
    return (
        f"{profile.source}: [park] z_mm = {emit.fmt(profile.park_mm.z)} is below the travel height "
        f"{emit.fmt(floor)} (calibration.surface_z_mm {emit.fmt(profile.calibration.surface_z_mm)} + "
        f"motion.safe_height_mm {emit.fmt(profile.safe_height_mm)}): the probe parks at Z {emit.fmt(floor)}"
    )

"""Validation before any G-code text exists: targets inside the bed and soft limits, press depth, feeds.

`check_press_plan` takes every press target in the printer frame and raises one ConfigError
naming each offending press (id and position) and the limit it breaks. It is called by
`program.build_program` before a single line is formatted, and by `neatskin gcode check` on a
parsed file (`check_moves`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from neatskin.errors import ConfigError, Problem
from neatskin.gcode.emit import PHASES
from neatskin.gcode.machine import Machine, Move
from neatskin.gcode.parse import TEXT_COMMANDS
from neatskin.gcode.profile import PrinterProfile

DEPTH_MARGIN_MM = 0.5  # the probe stops at least this far above the skin's underside
_MAX_LISTED = 12


def check_press_plan(
    profile: PrinterProfile,
    printer_x_mm: np.ndarray,
    printer_y_mm: np.ndarray,
    press_ids: np.ndarray,
    position_ids: np.ndarray,
    depth_mm: float,
    thickness_mm: float,
    depth_margin_mm: float = DEPTH_MARGIN_MM,
    source: str = "<program>",
) -> None:
    """Raise one ConfigError listing every press whose target breaks a limit (nothing is emitted)."""
    problems: list[Problem] = []
    cal = profile.calibration
    limit = thickness_mm - depth_margin_mm
    if not depth_mm > 0:
        problems.append(
            Problem(
                f"press depth {depth_mm} mm must be > 0 (below the surface)",
                source,
                "press.depth_mm",
                "set depth_mm to how far below the skin's top surface the probe goes",
            )
        )
    elif depth_mm > limit:
        problems.append(
            Problem(
                f"press depth {depth_mm} mm is beyond the skin thickness {thickness_mm} mm minus the "
                f"{depth_margin_mm} mm margin (limit {limit:g} mm)",
                source,
                "press.depth_mm",
                f"set depth_mm <= {limit:g}",
            )
        )
    xy_max = min(profile.max_feed_mm_s.x, profile.max_feed_mm_s.y)
    for key, value, vmax in (
        ("travel_feed_mm_s", profile.travel_feed_mm_s, xy_max),
        ("z_feed_mm_s", profile.z_feed_mm_s, profile.max_feed_mm_s.z),
        ("press_feed_mm_s", profile.press_feed_mm_s, profile.max_feed_mm_s.z),
    ):
        if value > vmax:
            problems.append(
                Problem(
                    f"{key} = {value} mm/s exceeds the printer maximum {vmax} mm/s",
                    profile.source,
                    f"motion.{key}",
                    f"set {key} <= {vmax}",
                )
            )
    z_safe = cal.surface_z_mm + profile.safe_height_mm
    z_press = cal.surface_z_mm - depth_mm
    if z_safe > profile.soft_max_mm.z:
        problems.append(
            Problem(
                f"safe travel height z = {z_safe:g} mm is above the z soft limit {profile.soft_max_mm.z:g} mm",
                profile.source,
                "motion.safe_height_mm",
                "lower safe_height_mm or check calibration.surface_z_mm",
            )
        )
    if z_press < profile.soft_min_mm.z and 0 < depth_mm <= limit:  # a depth past the skin is reported above
        problems.append(
            Problem(
                f"press depth reaches z = {z_press:g} mm, below the z soft limit {profile.soft_min_mm.z:g} mm",
                profile.source,
                "calibration.surface_z_mm",
                "re-measure surface_z_mm (the skin's top surface in printer z) or lower depth_mm",
            )
        )
    x = np.asarray(printer_x_mm, float)
    y = np.asarray(printer_y_mm, float)
    (lo_x, lo_y, _), (hi_x, hi_y, _) = profile.soft_box_mm
    checks = (("x", x, lo_x, hi_x), ("y", y, lo_y, hi_y))
    # one problem per axis, whatever the number of presses: a wrong offset moves them all, and is one mistake
    press_ids = np.asarray(press_ids)
    position_ids = np.asarray(position_ids)
    for axis, values, lo, hi in checks:
        out = ~np.isfinite(values) | (values < lo) | (values > hi)
        if not out.any():
            continue
        first = int(np.flatnonzero(out)[0])
        v = float(values[first])
        message = (
            f"press {int(press_ids[first])} (position {int(position_ids[first])}) goes to printer {axis} = "
            f"{v:.3f} mm, outside the bed and soft limits [{lo:g}, {hi:g}] mm"
        )
        n_out = int(out.sum())
        if n_out > 1:
            reach = values[out][np.isfinite(values[out])]
            span = f", {axis} from {float(reach.min()):.3f} to {float(reach.max()):.3f} mm" if reach.size else ""
            n_positions = len(np.unique(position_ids[out]))
            more = "so does 1 more press" if n_out == 2 else f"so do {n_out - 1} more presses"
            message += f"; {more} ({n_positions} position{'s' if n_positions > 1 else ''} in all{span})"
        problems.append(
            Problem(
                message,
                source,
                f"press {int(press_ids[first])}",
                "move the skin or refit the calibration offset/rotation (printer profile [calibration]) "
                "so every position lands on the bed",
            )
        )
    if problems:
        raise ConfigError(problems=problems)


def check_moves(
    profile: PrinterProfile, lines, source: str = "<program>", line_numbers: Sequence[int] | None = None
) -> list[Problem]:
    """Problems with a parsed program, stepped on the machine model (gcode.machine): G0/G1 targets
    outside the bed or soft limits, relative moves from an unknown position, feeds over the maxima.
    Each names `line N` (line_numbers[k] of the k-th command) or, without numbers, `command k`."""
    problems: list[Problem] = []
    lo, hi = profile.soft_box_mm  # the simulated printer clamps homed axes to the same box
    fmax = max(profile.max_feed_mm_s)
    machine = Machine(profile)
    for k, line in enumerate(lines):
        where = _where(k, line_numbers)
        event = machine.step(line)
        if isinstance(event, Move):
            for k, letter in enumerate("XYZ"):
                if line.get(letter) is None:
                    continue
                value = event.end_mm[k]
                if value is None:
                    problems.append(
                        Problem(
                            f"relative {letter} move before the position is known",
                            source,
                            where,
                            "home (G28) or move absolutely first",
                        )
                    )
                elif not lo[k] <= value <= hi[k]:
                    problems.append(
                        Problem(
                            f"{line.raw.strip()!r} moves {letter} to {value:g} mm, outside [{lo[k]:g}, {hi[k]:g}] mm",
                            source,
                            where,
                            "regenerate the program with a calibration that fits the bed",
                        )
                    )
            f = line.get("F")
            if f is not None and f / 60.0 > fmax:
                problems.append(
                    Problem(
                        f"feed F{f:g} ({f / 60:g} mm/s) exceeds every axis maximum",
                        source,
                        where,
                        f"use F <= {fmax * 60:g}",
                    )
                )
        if len(problems) > _MAX_LISTED:
            break
    return problems


def check_phases(lines, source: str = "<program>", line_numbers: Sequence[int] | None = None) -> list[Problem]:
    """Problems with the marked phases: every `NS press=<id> phase=<name>` marker must be followed by
    commands ending in M400 before the next marker, phases in order travel, descend, press, lift."""
    problems: list[Problem] = []
    expected = 0
    previous: tuple[str, str] | None = None  # (where, marker text)
    last_code = None
    for k, line in enumerate(lines):
        n = _where(k, line_numbers)
        is_marker = line.code == "M118" and line.text.startswith("NS ")
        if is_marker:
            if previous is not None and last_code != "M400":
                problems.append(
                    Problem(
                        f"phase '{previous[1]}' does not end in M400",
                        source,
                        previous[0],
                        "end every marked phase with M400 so acquisition lines up with motion",
                    )
                )
            fields = dict(part.split("=", 1) for part in line.text[3:].split() if "=" in part)
            if "phase" in fields:
                if fields["phase"] != PHASES[expected % len(PHASES)]:
                    problems.append(
                        Problem(
                            f"phase '{fields['phase']}' where '{PHASES[expected % len(PHASES)]}' was expected",
                            source,
                            n,
                            "regenerate the program; phases run travel, descend, press, lift",
                        )
                    )
                expected += 1
            previous = (n, line.text[3:])
        last_code = line.code
        if len(problems) > _MAX_LISTED:
            break
    return problems


# What a press program may contain: what `gcode generate` emits, and reads that change nothing.
PRESS_COMMANDS = frozenset(
    {"G0", "G1", "G4", "G21", "G28", "G90", "G91", "M17", "M18", "M82", "M83", "M84", "M105", "M114", "M115"}
    | {"M117", "M118", "M119", "M211", "M400"}
)
# Commands a press program must never contain, and why.
REFUSED_COMMANDS = {
    "M500": "writes the settings to the EEPROM",
    "M501": "replaces the live settings with the EEPROM's",
    "M502": "resets the settings to the factory defaults",
    "M104": "heats the hotend",
    "M109": "heats the hotend and waits",
    "M140": "heats the bed",
    "M190": "heats the bed and waits",
    "M141": "heats the chamber",
    "M191": "heats the chamber and waits",
    "M303": "runs a PID autotune, which heats",
    "M112": "is an emergency stop: the printer halts and needs a reset",
    "G92": "redefines the coordinate system (press programs rely on homed machine coordinates)",
}


# Stock Marlin keeps MAX_CMD_SIZE - 1 = 95 characters of a line (queue.cpp drops the rest; a comment is not
# stored). The host frames a command as `N<n> <command>*<cs>`: with up to 7 digits of line number and 3 of
# checksum that leaves 95 - 13 characters for the command. A longer one loses its tail on the real firmware:
# with its number, the checksum, so the firmware asks for the line again for ever (`No Checksum with line number`).
MARLIN_MAX_CMD_SIZE = 96
MAX_COMMAND_CHARS = MARLIN_MAX_CMD_SIZE - 1 - len("N1234567 ") - len("*255")
_FRAMING = re.compile(r"^\s*N\s*\d+\s*|\*\s*\d+\s*$", re.IGNORECASE)
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_CODE = re.compile(r"[A-Za-z]\s*\d+(?:\.\d+)?")


def firmware_text_problem(line) -> tuple[str, str] | None:
    """(what, fix) when the real firmware would not run the line as written, else None.

    Stock Marlin (GCODE_CASE_INSENSITIVE off) answers `echo:Unknown command` to a lower-case command letter and
    skips a lower-case parameter: `G1 X5 y7` moves X only (the native build in ../shared/marlin does exactly
    that), while this parser, the G-code machine model and the simulated printer read it as a move in Y. The
    text of M117/M118 and comments may be in any case. Past MAX_COMMAND_CHARS the firmware loses the line's tail."""
    body = _FRAMING.sub("", line.raw.partition(";")[0]).strip()
    head = _CODE.match(body)
    if head is None:
        return None
    lower = head.group(0)[0].islower()
    if not lower and line.code not in TEXT_COMMANDS:
        lower = any(c.islower() for c in _NUMBER.sub("", body[head.end() :]))
    if lower:
        return (
            f"{body!r} has a lower-case letter: stock Marlin answers 'Unknown command' to a lower-case command "
            "and ignores a lower-case parameter (G1 X5 y7 moves X only), while this check would read it as a move",
            f"write the command and its parameter letters in upper case ({body.upper()!r})",
        )
    if len(body) > MAX_COMMAND_CHARS:
        return (
            f"the command is {len(body)} characters: Marlin keeps {MARLIN_MAX_CMD_SIZE - 1} of a line, its line "
            "number and checksum included, and loses the rest (a numbered line then fails its checksum on every resend)",
            f"shorten it to at most {MAX_COMMAND_CHARS} characters (drop repeated spaces, or split the move)",
        )
    return None


def check_commands(lines, source: str = "<program>", line_numbers: Sequence[int] | None = None) -> list[Problem]:
    """One problem per command a press program must never contain: EEPROM writes, heaters, M112, G92,
    any command outside PRESS_COMMANDS (unknown or unsupported), and any the real firmware would not run as
    written (`firmware_text_problem`: lower case, too long). Every offending line is listed."""
    problems: list[Problem] = []
    allowed = ", ".join(sorted(PRESS_COMMANDS, key=lambda c: (c[0], int(float(c[1:])))))
    for k, line in enumerate(lines):
        code = line.code
        as_written = firmware_text_problem(line)
        if as_written is not None:
            problems.append(Problem(as_written[0], source, _where(k, line_numbers), as_written[1]))
            continue
        if code in PRESS_COMMANDS:
            continue
        why = REFUSED_COMMANDS.get(code, "is not a command a press program uses (unknown or unsupported here)")
        problems.append(
            Problem(
                f"{line.raw.strip()!r}: {code} {why}",
                source,
                _where(k, line_numbers),
                f"remove it; a press program holds only {allowed}",
            )
        )
    return problems


def _where(k: int, line_numbers: Sequence[int] | None) -> str:
    return f"line {line_numbers[k]}" if line_numbers is not None else f"command {k + 1}"

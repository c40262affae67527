"""G-code text: number formatting, the header, preamble and postamble, and the program as lines or one string.

User text (campaign, layout and printer names) only ever lands in comments, and `safe_text`
refuses anything that could end a comment or start a command there: newline, carriage return,
';', '*', and every other control character. Commands never contain user text.
"""

from __future__ import annotations

import os
import unicodedata
from collections.abc import Iterable, Iterator, Sized
from pathlib import Path
from typing import Protocol

import neatskin
from neatskin.errors import ConfigError

PHASES = ("travel", "descend", "press", "lift")
"""The phases of a press, in order; each starts with a marker (`marker`) and ends in M400."""


class _Calibration(Protocol):
    @property
    def offset_x_mm(self) -> float: ...
    @property
    def offset_y_mm(self) -> float: ...
    @property
    def rotation_deg(self) -> float: ...
    @property
    def surface_z_mm(self) -> float: ...


class _Phase(Protocol):
    @property
    def lines(self) -> tuple[str, ...]: ...


class _Block(Protocol):
    @property
    def press_id(self) -> int: ...
    @property
    def position_id(self) -> int: ...
    @property
    def repeat(self) -> int: ...
    @property
    def x_mm(self) -> float: ...
    @property
    def y_mm(self) -> float: ...

    @property
    def phases(self) -> tuple[_Phase, ...]: ...


class PressProgram(Protocol):
    """What the text of a program is made of (`neatskin.gcode.program.PressProgram` has it): a structural type,
    so this module, the lowest of gcode/, imports no program."""

    @property
    def name(self) -> str: ...
    @property
    def seed(self) -> int: ...
    @property
    def layout_name(self) -> str: ...
    @property
    def printer_name(self) -> str: ...
    @property
    def depth_mm(self) -> float: ...
    @property
    def hold_s(self) -> float: ...
    @property
    def hold_in_gcode(self) -> bool: ...
    @property
    def route_mm(self) -> float: ...
    @property
    def route_unordered_mm(self) -> float | None: ...
    @property
    def preamble(self) -> tuple[str, ...]: ...
    @property
    def postamble(self) -> tuple[str, ...]: ...

    @property
    def calibration(self) -> _Calibration: ...
    @property
    def positions(self) -> Sized: ...
    @property
    def presses(self) -> _Presses: ...


class _Presses(Protocol):
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[_Block]: ...


FORBIDDEN = {"\n": "a newline", "\r": "a carriage return", ";": "';'", "*": "'*'"}
MARKER = "M118 E1 NS"


def safe_text(value: str, field: str, source: str = "<memory>") -> str:
    """Return `value` if it is safe inside a G-code comment; ConfigError otherwise."""
    if not isinstance(value, str):
        raise ConfigError(f"{field} must be text, got {value!r}", file=source, field=field, fix="quote it in the TOML")
    for char in value:
        what = FORBIDDEN.get(char)
        if what is None and unicodedata.category(char) in ("Cc", "Cf", "Zl", "Zp"):
            what = f"the control character U+{ord(char):04X}"
        if what is None and not char.isascii():
            what = f"the non-ASCII character {char!r} (U+{ord(char):04X}); G-code files are ASCII"
        if what is not None:
            raise ConfigError(
                f"{field} {value!r} contains {what}, which could inject a G-code command",
                file=source,
                field=field,
                fix="use ASCII letters, digits, spaces and simple punctuation (no ';', '*' or line breaks)",
            )
    return value


def fmt(value: float) -> str:
    """A coordinate or feed as G-code text: at most 3 decimals, no trailing zeros, never '-0'."""
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def feed(mm_s: float) -> str:
    return fmt(mm_s * 60.0)


def marker(press_id: int, phase: str) -> str:
    """The echo the runner matches on the wire: the printer answers `echo:NS press=<id> phase=<name>`."""
    return f"{MARKER} press={press_id} phase={phase}"


def header_lines(program: PressProgram) -> list[str]:
    p = program
    lines = [
        f"; neatskin-rig {neatskin.__version__} press program",
        f"; protocol: {safe_text(p.name, 'campaign.name')}",
        f"; seed: {p.seed}",
        f"; layout: {safe_text(p.layout_name, 'skin.name')}",
        f"; printer: {safe_text(p.printer_name, 'printer.name')}",
        f"; positions: {len(p.positions)}, presses: {len(p.presses)}, depth_mm: {fmt(p.depth_mm)}, "
        f"hold_s: {fmt(p.hold_s)}, hold_in_gcode: {str(p.hold_in_gcode).lower()}",
        f"; calibration: offset_x_mm={fmt(p.calibration.offset_x_mm)} offset_y_mm={fmt(p.calibration.offset_y_mm)} "
        f"rotation_deg={fmt(p.calibration.rotation_deg)} surface_z_mm={fmt(p.calibration.surface_z_mm)}",
    ]
    if p.route_unordered_mm is not None:
        lines.append(f"; travel ordering: route {fmt(p.route_mm)} mm instead of {fmt(p.route_unordered_mm)} mm")
    return lines


def preamble_lines(raise_mm: float) -> tuple[str, ...]:
    """Units, absolute mode, soft endstops on, then home with Z raised by `raise_mm` first (the profile's surface +
    safe height). G28's R word: Marlin 2.1 (G28.cpp, `seenR`) raises Z by R relative to where it is, homed or not,
    before homing X, Y or Z; a plain G28 raises only Z_CLEARANCE_FOR_HOMING (5 mm stock), which from a probe
    left in the skin (a crash, a kill mid-press) drags it through the skin to X and Y's endstops."""
    return ("G21", "G90", "M211 S1", f"G28 R{fmt(raise_mm)}", "M400")


def program_lines(program: PressProgram) -> Iterator[str]:
    """The program's file lines (header and comments included, no newlines), made as they are read."""
    yield from header_lines(program)
    yield "; preamble"
    yield from program.preamble
    for block in program.presses:
        yield (
            f"; press {block.press_id} position {block.position_id} repeat {block.repeat} "
            f"sensor x={fmt(block.x_mm)} y={fmt(block.y_mm)}"
        )
        for phase in block.phases:
            yield from phase.lines
    yield "; postamble"
    yield from program.postamble


def program_text(program: PressProgram) -> str:
    """The whole program as text, one command per line, ending in a newline (write_lines_atomic writes
    program_lines without holding it)."""
    return "\n".join(program_lines(program)) + "\n"


def check_output_path(path: Path, option: str) -> None:
    """ConfigError unless `path` can be a file we write: not a folder, its parent a folder or creatable."""
    if path.is_dir():
        raise ConfigError(
            f"{path} is a folder, not a file", file=str(path), field=option, fix=f"give {option} a file name in it"
        )
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(
            f"cannot create {path}: {parent} is a file, not a folder",
            file=str(path),
            field=option,
            fix=f"give {option} a path in a folder",
        )


def write_text_atomic(path: Path, text: str, encoding: str, option: str) -> None:
    """Write `text` to `path` through a temp file and a rename: either the whole file or nothing (no temp
    file left behind on any failure). Encoding and file system failures are one ConfigError naming the file."""
    check_output_path(path, option)
    _write_atomic(path, (_encode(text, encoding, path, option),), option)


WRITE_BLOCK_LINES = 4096  # lines encoded and written at a time by write_lines_atomic


def write_lines_atomic(path: Path, lines: Iterable[str], encoding: str, option: str) -> int:
    """write_text_atomic for `lines` (each written with a newline), WRITE_BLOCK_LINES at a time, so a large
    program's text is never held whole; returns the number of lines written. The same errors, and no temp
    file left on any failure (an encoding failure may leave the folder it created)."""
    check_output_path(path, option)
    written = 0

    def blocks() -> Iterator[bytes]:
        nonlocal written
        block: list[str] = []
        for line in lines:
            block.append(line)
            if len(block) == WRITE_BLOCK_LINES:
                written += len(block)
                yield _encode("\n".join(block) + "\n", encoding, path, option)
                block = []
        if block:
            written += len(block)
            yield _encode("\n".join(block) + "\n", encoding, path, option)

    _write_atomic(path, blocks(), option)
    return written


def _encode(text: str, encoding: str, path: Path, option: str) -> bytes:
    try:
        return text.encode(encoding)
    except UnicodeEncodeError as exc:
        bad = exc.object[exc.start : exc.end]
        raise ConfigError(
            f"cannot write {bad!r} (U+{ord(bad[0]):04X}) as {encoding}",
            file=str(path),
            field=option,
            fix="use ASCII in the names that land in the file (campaign, layout and printer names)",
        ) from None


def _write_atomic(path: Path, data: Iterable[bytes], option: str) -> None:
    """Write the blocks of `data` to `path` through a temp file and a rename: the whole file or nothing."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as handle:
            for block in data:
                handle.write(block)
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        raise ConfigError(
            f"cannot write {path}: {exc.strerror or exc}",
            file=str(path),
            field=option,
            fix=f"give {option} a writable file path (a folder you may write to, with free space)",
        ) from exc
    except BaseException:
        _remove(tmp)
        raise


def _remove(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass

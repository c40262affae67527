"""Parsing Marlin G-code lines: the subset this toolkit emits plus common Marlin commands and host framing.

`parse_line` turns one line of text into a `GcodeLine` (code, letter parameters, comment) or
None for a blank or comment-only line. It tolerates the host framing Marlin receives on the
serial line, `N123 G1 X1*45`: the line number and checksum come back as separate fields and
`GcodeLine.checksum_ok` says whether the checksum matches. `checksum(text)` is Marlin's: the
XOR of every byte before the '*'.

Parameters map an upper-case letter to a float (`X10.5` -> {"X": 10.5}); a letter with no
value (`G28 X`) maps to the empty string. M117/M118 (and the SD-card file commands) keep their
free text in the string parameter "text"; M118's leading A1/E1/Pn flags are still parsed as
numbers. Numbers are finite and within +-2^31: `X1e999`, `Xnan`, `Xinf` and `X1e300` are syntax errors. A syntax error raises
`GcodeSyntaxError` (a ConfigError) naming the line.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from typing import NoReturn

from neatskin.errors import ConfigError, Problem
from neatskin.tomlfile import read_text_capped

# Commands whose argument is free text, not letter/number parameters.
TEXT_COMMANDS = frozenset({"M23", "M28", "M30", "M32", "M117", "M118", "M928"})
_CODE_RE = re.compile(r"([GMTD])\s*(\d+(?:\.\d+)?)", re.IGNORECASE)
_NUMBER_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_LINE_NUMBER_RE = re.compile(r"N\s*(\d+)\s*", re.IGNORECASE)
_M118_FLAG_RE = re.compile(r"([AEP])(\d+)(?=\s|$)")
MAX_MAGNITUDE = 2.0**31  # Marlin's line numbers are longs; no coordinate, feed or time is anywhere near
_NOT_FINITE_RE = re.compile(r"[+-]?(?:nan|inf)", re.IGNORECASE)
# the common line, `G1 X10 Y-2.5 F6000`: no framing, comment, exponent, lower case or number >= 1e9 (the fast path)
_SIMPLE_RE = re.compile(r"([GM])([1-9]\d*|0)((?:[ \t]+[A-Z][+-]?(?:\d{1,9}(?:\.\d*)?|\.\d+))*)[ \t]*")
_SIMPLE_PARAM_RE = re.compile(r"([A-Z])([+-]?[\d.]+)")


class GcodeSyntaxError(ConfigError):
    """A line of G-code that cannot be parsed."""


@dataclass(frozen=True)
class GcodeLine:
    """One parsed command. `raw` is the line as given (without the end-of-line characters)."""

    code: str
    params: dict[str, float | str] = field(default_factory=dict, hash=False)
    comment: str = ""
    raw: str = ""
    line_number: int | None = None
    checksum: int | None = None

    @property
    def checksum_ok(self) -> bool | None:
        """True/False when the line carried a '*' checksum, None when it had none."""
        if self.checksum is None:
            return None
        body = self.raw.split(";", 1)[0]
        return checksum(body) == self.checksum

    def get(self, letter: str, default: float | None = None) -> float | None:
        """A numeric parameter, or `default` when absent or given without a value."""
        value = self.params.get(letter)
        return value if isinstance(value, float) else default

    @property
    def text(self) -> str:
        value = self.params.get("text", "")
        return value if isinstance(value, str) else ""


def checksum(text: str) -> int:
    """Marlin's checksum: XOR of every byte of `text` before the first '*' (all of it if none)."""
    body = text.split("*", 1)[0].encode("ascii", errors="replace")
    value = 0
    for byte in body:
        value ^= byte
    return value


def frame_line(command: str, line_number: int) -> str:
    """Frame a command the way a host sends it: `N<n> <command>*<checksum>` (no newline)."""
    body = f"N{line_number} {command.strip()}"
    return f"{body}*{checksum(body)}"


def parse_line(text: str, *, source: str = "<line>", line_no: int | None = None) -> GcodeLine | None:
    """Parse one line; None for blank or comment-only lines. Raises GcodeSyntaxError."""
    raw = text.rstrip("\r\n")
    simple = _SIMPLE_RE.fullmatch(raw)
    if simple is not None:
        code = simple.group(1) + simple.group(2)
        if code not in TEXT_COMMANDS:
            params: dict[str, float | str] = {k: float(v) for k, v in _SIMPLE_PARAM_RE.findall(simple.group(3))}
            return GcodeLine(code, params, "", raw, None, None)
    body, _, comment = raw.partition(";")
    comment = comment.strip()
    check: int | None = None
    if "*" in body:
        body, _, check_text = body.rpartition("*")
        check_text = check_text.strip()
        if not check_text.isdigit():
            _fail(raw, f"checksum '*{check_text}' is not a number", source, line_no)
        check = int(check_text)
    body = body.strip()
    line_number: int | None = None
    match = _LINE_NUMBER_RE.match(body)
    if match:
        line_number = int(match.group(1))
        body = body[match.end() :]
    if not body:
        if line_number is not None or check is not None:
            _fail(raw, "a framed line with no command", source, line_no)
        return None
    match = _CODE_RE.match(body)
    if not match:
        _fail(raw, f"'{body.split()[0]}' is not a G, M or T command", source, line_no)
    code = f"{match.group(1).upper()}{_normalise_number(match.group(2))}"
    rest = body[match.end() :]
    params = _text_params(code, rest) if code in TEXT_COMMANDS else _letter_params(rest, raw, source, line_no)
    return GcodeLine(code, params, comment, raw, line_number, check)


def parse_program(text: str, source: str = "<program>") -> tuple[GcodeLine, ...]:
    """Parse every line of a program; one GcodeSyntaxError listing every bad line."""
    return tuple(line for _, line in parse_numbered(text, source))


def parse_numbered(text: str, source: str = "<program>") -> tuple[tuple[int, GcodeLine], ...]:
    """(line number in the text, command) of every command; one GcodeSyntaxError listing every bad line."""
    lines: list[tuple[int, GcodeLine]] = []
    problems: list[Problem] = []
    for number, line in enumerate(text.splitlines(), start=1):
        try:
            parsed = parse_line(line, source=source, line_no=number)
        except GcodeSyntaxError as exc:
            problems.extend(exc.problems)
            continue
        if parsed is not None:
            lines.append((number, parsed))
    if problems:
        raise GcodeSyntaxError(problems=problems)
    return tuple(lines)


MAX_PROGRAM_BYTES = 64 * 1024 * 1024  # the paper campaign's program is about 1 MB


def read_program_file(path: str | os.PathLike[str], max_bytes: int = MAX_PROGRAM_BYTES) -> str:
    """The text of a G-code file: a regular file of at most max_bytes, no NUL bytes, UTF-8 (read past a
    byte-order mark). Anything else is one ConfigError naming the file and the fix (a device is refused unread,
    a parquet or a binary never read past the cap); the toolkit's one capped reader, `tomlfile.read_text_capped`."""
    return read_text_capped(
        path,
        "G-code file",
        "check the path; give the .gcode file written by `neatskin gcode generate`",
        max_bytes,
        kind="G-code file",
        refuse_nul=True,
    )


def _normalise_number(digits: str) -> str:
    whole, _, sub = digits.partition(".")
    whole = str(int(whole))
    return f"{whole}.{sub}" if sub else whole


def _text_params(code: str, rest: str) -> dict[str, float | str]:
    params: dict[str, float | str] = {}
    text = rest.lstrip()
    if code == "M118":
        while True:
            flag = _M118_FLAG_RE.match(text)
            if not flag:
                break
            params[flag.group(1)] = float(flag.group(2))
            text = text[flag.end() :].lstrip()
    params["text"] = text.rstrip()
    return params


def _letter_params(rest: str, raw: str, source: str, line_no: int | None) -> dict[str, float | str]:
    params: dict[str, float | str] = {}
    pos = 0
    while pos < len(rest):
        char = rest[pos]
        if char.isspace():
            pos += 1
            continue
        if not char.isalpha():
            _fail(raw, f"unexpected '{char}' where a parameter letter belongs", source, line_no)
        letter = char.upper()
        pos += 1
        while pos < len(rest) and rest[pos] == " " and pos + 1 < len(rest) and _NUMBER_RE.match(rest, pos + 1):
            pos += 1  # Marlin accepts "X 10"
        number = _NUMBER_RE.match(rest, pos)
        if number:
            value = float(number.group(0))
            if not math.isfinite(value):
                _fail(raw, f"'{letter}{number.group(0)}' is not a finite number", source, line_no)
            if abs(value) > MAX_MAGNITUDE:
                _fail(raw, f"'{letter}{number.group(0)}' is beyond +-2^31 (Marlin's range)", source, line_no)
            params[letter] = value
            pos = number.end()
            if pos < len(rest) and not rest[pos].isspace() and not rest[pos].isalpha():
                _fail(raw, f"malformed number for '{letter}'", source, line_no)
        elif _NOT_FINITE_RE.match(rest, pos):
            _fail(raw, f"'{letter}{rest[pos:].split()[0]}' is not a finite number", source, line_no)
        else:
            params[letter] = ""
    return params


def _fail(raw: str, message: str, source: str, line_no: int | None) -> NoReturn:
    where = f"line {line_no}" if line_no is not None else "line"
    raise GcodeSyntaxError(
        f"{message}: {raw!r}",
        file=source,
        field=where,
        fix="write one command per line as a letter code and parameters, e.g. 'G1 X10 Y20 F3000'",
    )

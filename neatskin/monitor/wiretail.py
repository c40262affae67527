"""The wire log's tail as the monitor shows it: its last lines as text, and the printer's last position from them.

Reads only the end of `wire.log` (every byte to and from the printer, `neatskin.marlin.wirelog`), so a long
campaign's log costs one seek; the position is an M114 report when one is newer than the last
commanded G0/G1 move, else that move's target.
"""

from __future__ import annotations

import ast
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

WIRE_LOG = "wire.log"
WIRE_TAIL_BYTES = 64 * 1024
WIRE_TAIL_LINES = 40
_AXIS = re.compile(r"\b([XYZ])(-?\d+(?:\.\d*)?)")
_REPORT = re.compile(r"X:(-?\d+(?:\.\d*)?) Y:(-?\d+(?:\.\d*)?) Z:(-?\d+(?:\.\d*)?)")
# a sent G0/G1 line; one wire-log entry holds every line of one write (pipelined lines: several, `\n`-separated)
_SENT = re.compile(r"(?:> b'|\\n)N\d+ (G[01]\b[^*]*)\*")

_WIRE_ENTRY = re.compile(r"^\d{4}-\d\d-\d\dT(\d\d:\d\d:\d\d)(\.\d{1,3})?\d*Z?\s+\S+\s+(\S) (b(['\"]).*\5)\s*$")
WIRE_DIRECTIONS = {">": "→", "<": "←", "#": "#"}


def wire_text(lines: Sequence[str]) -> list[str]:
    """The wire log's entries as text: one line per line on the wire, `HH:MM:SS.mmm → N1 G21*27` (UTC, as the
    log), bytes decoded instead of Python's b'...' reprs; an entry that is not one is kept as it is."""
    out: list[str] = []
    for entry in lines:
        match = _WIRE_ENTRY.match(entry)
        if match is None:
            out.append(entry)
            continue
        try:
            data = ast.literal_eval(match.group(4))
        except (ValueError, SyntaxError):
            out.append(entry)
            continue
        clock = match.group(1) + (match.group(2) or "")
        arrow = WIRE_DIRECTIONS.get(match.group(3), match.group(3))
        text = data.decode("utf-8", "replace") if isinstance(data, bytes) else str(data)
        out.extend(f"{clock} {arrow} {part}" for part in (text.splitlines() or [""]))
    return out[-WIRE_TAIL_LINES:]


def wire_tail(folder: Path) -> tuple[list[str], dict[str, Any] | None]:
    """The wire log's last lines and the printer's last position: an M114 report if one is newer than the
    last commanded move, else the commanded target (printer coordinates)."""
    path = folder / WIRE_LOG
    try:
        with open(path, "rb") as handle:
            size = handle.seek(0, os.SEEK_END)
            handle.seek(max(0, size - WIRE_TAIL_BYTES))
            text = handle.read().decode("utf-8", "replace")
    except OSError:
        return [], None
    lines = text.splitlines()[1:] if size > WIRE_TAIL_BYTES else text.splitlines()
    position: dict[str, Any] | None = None
    axes: dict[str, float] = {}
    for line in lines:
        report = _REPORT.search(line)
        if report and "< " in line:
            axes = dict(zip("XYZ", map(float, report.groups())))
            position = {"source": "M114", **axes, "at": line[:27]}
            continue
        if "> b'" not in line:
            continue
        for sent in _SENT.finditer(line):
            axes = {**axes, **{a: float(v) for a, v in _AXIS.findall(sent.group(1))}}
            position = {"source": "commanded", **axes, "at": line[:27]}
    return lines[-WIRE_TAIL_LINES:], position

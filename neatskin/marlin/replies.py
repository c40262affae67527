"""Marlin's host protocol as pure functions: line framing, reply classification, M114/M119 parsing.

Nothing here touches a port. The reply texts are Marlin's own (language.h / queue.cpp):
`ok` (or `ok N12 P15 B3` with ADVANCED_OK), `Resend: 12` (or `rs 12`),
`Error:checksum mismatch, Last Line: 11`, `Error:Line Number is not Last Line Number+1, Last Line: 11`,
`Error:No Checksum with line number, Last Line: 11`, `echo:busy: processing`,
`echo:Unknown command: "G999"`, `Error:Printer halted. kill() called!`,
`Error:Printer stopped due to errors. ...`, `start`, `//action:...`.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from typing import NamedTuple

from neatskin.gcode.parse import checksum

#: Marlin's reply texts, shared by the driver's tests and the simulated printer.
OK = "ok"
START = "start"
RESEND = "Resend: "
ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "
ERR_KILLED = "Printer halted. kill() called!"
ERR_STOPPED = (
    "Printer stopped due to errors. Fix the error and use M999 to restart. "
    "(Temperature is reset. Set it after restarting)"
)
BUSY_PROCESSING = "busy: processing"
UNKNOWN_COMMAND = 'Unknown command: "'
HOME_FIRST = "Home XYZ First"

#: The echo text of the driver's lost-`ok` probe (`M118 E1 <PROBE_TAG> <n>`).
PROBE_TAG = "neatskin-probe"


class Kind(enum.Enum):
    OK = "ok"
    RESEND = "resend"
    COMM_ERROR = "comm_error"  # checksum / line number / no checksum: recoverable
    HALTED = "halted"  # kill() called: needs a reset
    STOPPED = "stopped"  # Stop(): needs M999
    ERROR = "error"  # any other Error: line
    START = "start"
    BUSY = "busy"
    WAIT = "wait"
    UNKNOWN_COMMAND = "unknown_command"
    REJECTED = "rejected"  # the command was taken but refused (e.g. a move before homing)
    PROBE_ECHO = "probe_echo"
    ECHO = "echo"
    ACTION = "action"
    DATA = "data"  # anything else: M114 position, M119 endstops, temperatures...


class Reply(NamedTuple):
    """One reply line, classified. A NamedTuple (immutable, as the frozen dataclass it replaces, and cheaper to
    make): one is made for every line the printer sends."""

    kind: Kind
    text: str
    number: int | None = None  # ok N / Resend N / Last Line N / probe number
    planner_free: int | None = None  # ADVANCED_OK P
    buffer_free: int | None = None  # ADVANCED_OK B


_OK_NPB = re.compile(r"ok N(\d+) P(\d+) B(\d+)")  # ADVANCED_OK as Marlin prints it: the common reply, one match
_OK_N = re.compile(r"\bN(\d+)")
_OK_P = re.compile(r"\bP(\d+)")
_OK_B = re.compile(r"\bB(\d+)")
_RESEND = re.compile(r"^(?:Resend|rs)\s*:?\s*N?:?\s*(\d+)", re.IGNORECASE)
_LAST_LINE = re.compile(r"Last Line:\s*(-?\d+)")
_EXPECTED_LINE = re.compile(r"expected line\s*(\d+)", re.IGNORECASE)
_COMM_ERROR = re.compile(r"checksum|line ?number|last line", re.IGNORECASE)
_HOME_FIRST = re.compile(r"^(?:echo:)?\s*Home [XYZ]+ first", re.IGNORECASE)


def frame(command: str, line_number: int) -> bytes:
    """`N<n> <command>*<cs>\\n`, the checksum Marlin's XOR of every byte before '*'."""
    body = f"N{line_number} {command.strip()}"
    return f"{body}*{checksum(body)}\n".encode("ascii")


def classify(line: str) -> Reply:
    """Classify one reply line (without its end-of-line characters)."""
    text = line.strip()
    if text == OK or text.startswith("ok ") or text.startswith("ok:"):
        advanced = _OK_NPB.fullmatch(text)  # the numbers the three searches below find in it, in one match
        if advanced is not None:
            return Reply(Kind.OK, text, int(advanced[1]), int(advanced[2]), int(advanced[3]))
        if " N" in text or " P" in text:
            return Reply(Kind.OK, text, _int(_OK_N.search(text)), _int(_OK_P.search(text)), _int(_OK_B.search(text)))
        return Reply(Kind.OK, text)
    match = _RESEND.match(text)
    if match:
        return Reply(Kind.RESEND, text, int(match.group(1)))
    if text == START:
        return Reply(Kind.START, text)
    if ERR_KILLED in text or "kill() called" in text:
        return Reply(Kind.HALTED, text)
    if "Printer stopped due to errors" in text:
        return Reply(Kind.STOPPED, text)
    if text.startswith("Error:") or text.startswith("Error "):
        last = _LAST_LINE.search(text)
        if last and (ERR_CHECKSUM in text or ERR_LINE_NO in text or ERR_NO_CHECKSUM in text):
            return Reply(Kind.COMM_ERROR, text, int(last.group(1)))
        expected = _EXPECTED_LINE.search(text)
        if expected:  # Repetier / OctoPrint: `Error: expected line 5 got 6`
            return Reply(Kind.COMM_ERROR, text, int(expected.group(1)) - 1)
        if _COMM_ERROR.search(text):  # `Error: Checksum mismatch`, `Error: Wrong checksum`, no `Last Line:`
            return Reply(Kind.COMM_ERROR, text, int(last.group(1)) if last else None)
        return Reply(Kind.ERROR, text)
    body = text[5:] if text.startswith("echo:") else text
    if body.startswith("busy:"):
        return Reply(Kind.BUSY, text)
    if text == "wait":
        return Reply(Kind.WAIT, text)
    if body.startswith(UNKNOWN_COMMAND):
        return Reply(Kind.UNKNOWN_COMMAND, text)
    if _HOME_FIRST.match(text):
        return Reply(Kind.REJECTED, text)
    if body.startswith(PROBE_TAG + " "):
        tail = body[len(PROBE_TAG) + 1 :].strip()
        if tail.isdigit():
            return Reply(Kind.PROBE_ECHO, text, int(tail))
    if text.startswith("echo:"):
        return Reply(Kind.ECHO, text)
    if text.startswith("//action:"):
        return Reply(Kind.ACTION, text)
    return Reply(Kind.DATA, text)


def _int(match: re.Match[str] | None) -> int | None:
    return int(match.group(1)) if match else None


@dataclass(frozen=True)
class Position:
    """The tool position from M114, mm in printer coordinates, and the stepper counts if reported."""

    x_mm: float
    y_mm: float
    z_mm: float
    e_mm: float = 0.0
    count: tuple[int, ...] | None = None


_M114 = re.compile(
    r"X:\s*(-?\d+(?:\.\d*)?)\s+Y:\s*(-?\d+(?:\.\d*)?)\s+Z:\s*(-?\d+(?:\.\d*)?)(?:\s+E:\s*(-?\d+(?:\.\d*)?))?"
)
_COUNT = re.compile(r"Count\s+X:\s*(-?\d+)\s+Y:\s*(-?\d+)\s+Z:\s*(-?\d+)")


def parse_m114(lines: list[str] | tuple[str, ...]) -> Position:
    """The first `X:.. Y:.. Z:..` line of an M114 reply (also `ok X:.. Y:..`, as OctoPrint's Virtual Printer
    answers); ValueError when there is none."""
    for line in lines:
        match = _M114.search(line)
        if match and not line.lstrip().startswith("Count"):
            count = _COUNT.search(line)
            return Position(
                float(match.group(1)),
                float(match.group(2)),
                float(match.group(3)),
                float(match.group(4) or 0.0),
                tuple(int(c) for c in count.groups()) if count else None,
            )
    raise ValueError(f"no position in M114 reply {list(lines)!r}")


_M119 = re.compile(r"^([a-z0-9_]+):\s*(open|TRIGGERED)\s*$", re.IGNORECASE)


def parse_m119(lines: list[str] | tuple[str, ...]) -> dict[str, bool]:
    """`x_min: open` / `z_min: TRIGGERED` lines -> {"x_min": False, "z_min": True}; ValueError if none."""
    states: dict[str, bool] = {}
    for line in lines:
        match = _M119.match(line.strip())
        if match:
            states[match.group(1).lower()] = match.group(2).upper() == "TRIGGERED"
    if not states:
        raise ValueError(f"no endstop states in M119 reply {list(lines)!r}")
    return states

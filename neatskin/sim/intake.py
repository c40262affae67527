"""The simulated Marlin's serial side: the receive ring, line numbers, checksums and resends, the command queue
and the reply bytes (Marlin 2.1's queue.cpp), without the commands' meaning (sim.firmware runs them).

A repeated line just below the counter is dropped silently (`marlin_version="2.0"` answers it with an error
instead); a bare `ok` follows every `Resend:`, as Marlin sends it (`ok_after_resend=False` leaves it out, as a
Repetier-like peer). Line faults (faults.FaultConfig: a dropped or corrupted line, a dropped or doubled reply)
are drawn from the seeded Generator the firmware hands over.
"""

from __future__ import annotations

import collections
import dataclasses
import re

import numpy as np

from neatskin.errors import ConfigError
from neatskin.gcode.parse import TEXT_COMMANDS, GcodeLine, checksum, parse_line
from neatskin.marlin import replies as R
from neatskin.sim.faults import FaultConfig
from neatskin.sim.settings import f32

_N = re.compile(r"N\s*(-?\d+)")
_DIGITS = re.compile(r"\d+")
_EOL = re.compile(rb"[\r\n]")
_FRAMED = re.compile(r"N(\d+)([^*]*)\*(\d+)")  # the common framed line: N<n> <command>*<checksum>
_PARSE_CACHE_LINES = 1024  # distinct command texts kept parsed (the repeated ones come first)
MAX_LINE_CHARS = 95  # Marlin's MAX_CMD_SIZE (96) less its terminating NUL
_AXES = "XYZE"
_COMMAND = re.compile(r"[GMT]\d")  # parser.cpp: the command letter, upper case (stock: not GCODE_CASE_INSENSITIVE)

#: A queued command: (line number, command, code, parsed, the line as received: M111 S1 echoes it)
Queued = tuple[int | None, str, str, GcodeLine | None, str]


class LineIntake:
    """Bytes in, queued commands out, and the reply bytes; the firmware (a subclass) runs the queue."""

    def __init__(
        self,
        faults: FaultConfig,
        rng: np.random.Generator,
        *,
        marlin_version: str,
        ok_after_resend: bool,
        bufsize: int,
        rx_buffer_size: int | None,
    ) -> None:
        self.faults = faults
        self.rng = rng
        self.marlin_version = marlin_version
        self.ok_after_resend = ok_after_resend
        self.bufsize = bufsize
        # the serial receive ring: bytes past it are lost, as on an AVR board (None: unbounded, as the
        # native build's HAL, which reads stdin only into free space)
        self.rx_buffer_size = rx_buffer_size
        self.rx_overflow_bytes = 0
        self.out = bytearray()
        self.dead = False
        self.closed = False
        self.halted = False
        self._parsed: dict[str, tuple[str, GcodeLine | None]] = {}
        self._clear_intake()

    def _clear_intake(self) -> None:
        """At boot: the ring, the queue and the line counter are empty."""
        self.rx = bytearray()
        self.queue: collections.deque[Queued] = collections.deque()
        self.last_n = 0

    def _kill(self) -> None:
        """M112: the firmware's to do (it stops the motion too)."""
        raise NotImplementedError

    def _quick_stop(self) -> None:
        """M410: the firmware's to do."""
        raise NotImplementedError

    # ---- output ---------------------------------------------------------------------------

    def take_output(self) -> bytes:
        data = bytes(self.out)
        self.out.clear()
        return data

    def _emit(self, text: str, *, is_ok: bool = False, eol: bytes = b"\n") -> None:
        if self.dead:
            return
        if is_ok and self.faults.drop_ok and self.rng.random() < self.faults.drop_ok:
            return
        line = text.encode("ascii") + eol
        self.out += line
        if self.faults.duplicate and self.rng.random() < self.faults.duplicate:
            self.out += line

    # ---- input ----------------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        if self.dead or self.halted:
            return  # a killed Marlin reads nothing until it is reset
        room = None if self.rx_buffer_size is None else self.rx_buffer_size - 1 - len(self.rx)
        if room is not None and len(data) > room:
            self.rx_overflow_bytes += len(data) - max(room, 0)
            data = data[: max(room, 0)]
        self.rx += data
        self._read_lines()

    def _read_lines(self) -> None:
        rx = self.rx
        while len(self.queue) < self.bufsize and not self.dead:
            eol = _EOL.search(rx)
            if eol is None:
                return
            cut = eol.start()
            raw = bytes(rx[:cut])
            del rx[: cut + 1]
            self._accept(raw)

    def _accept(self, raw: bytes) -> None:
        faults = self.faults
        if faults.drop_line and raw.strip() and self.rng.random() < faults.drop_line:
            return
        if faults.corrupt and raw.strip() and self.rng.random() < faults.corrupt:
            raw = self._corrupt(raw)
        # Marlin's reader (queue.cpp process_stream_char): a ';' starts a comment to the end of the line, a line keeps
        # its first MAX_CMD_SIZE - 1 characters, and one with nothing kept is skipped without a word (a line of
        # spaces is kept: it is an unknown command ""); the command starts after the leading spaces (not tabs)
        line = raw.decode("ascii", "replace").split(";", 1)[0][:MAX_LINE_CHARS]
        if not line or self.halted:
            return
        text = line.lstrip(" ")
        number = None
        framed = _FRAMED.fullmatch(text)
        if framed is not None and "M110" not in text:  # the common case, checked as the general path below
            number = int(framed.group(1))
            if not self._in_sequence(number):
                return
            if int(framed.group(3)) != checksum(text[: framed.start(3) - 1]):
                self._line_error(R.ERR_CHECKSUM)
                return
            self.last_n = number
            self._enqueue(number, framed.group(2).strip(), text)
            return
        if text.startswith("N"):
            is_m110 = "M110" in text
            npos = text
            if is_m110 and "N" in text[4:]:
                npos = text[text.index("N", 4) :]
            match = _N.match(npos)
            number = int(match.group(1)) if match else 0
            if not is_m110 and not self._in_sequence(number):
                return
            star = text.rfind("*")
            if star < 0:
                self._line_error(R.ERR_NO_CHECKSUM)
                return
            digits = _DIGITS.match(text, star + 1)
            if digits is None or int(digits.group(0)) != checksum(text[:star]):
                self._line_error(R.ERR_CHECKSUM)
                return
            self.last_n = number
            head = _N.match(text)
            self._enqueue(number, text[head.end() : star].strip() if head else text[:star].strip(), text)
            return
        if text.startswith("M112"):  # no emergency parser: queue.cpp kills on an unnumbered M112 as it reads it
            self._kill()
            return
        if text.startswith("M410"):  # ... and stops the motion on an unnumbered M410 (it is queued too)
            self._quick_stop()
        self._enqueue(number, text, text)

    def _in_sequence(self, number: int) -> bool:
        """True for the next line number; otherwise the line is refused (or dropped) here."""
        if number == self.last_n + 1:
            return True
        if not (self.marlin_version >= "2.1" and self.last_n - 1 <= number <= self.last_n):
            self._line_error(R.ERR_LINE_NO)
        # else: a repeat from a crossed resend, dropped without a word (Marlin 2.1)
        return False

    def _enqueue(self, number: int | None, text: str, raw: str) -> None:
        """Queue a command, parsed once (Marlin parses at execution; the result is the same).

        A campaign repeats most of its lines (`M400`, the descend and lift moves): each distinct
        text is parsed once (a bounded cache of immutable parses)."""
        parsed = self._parsed.get(text)
        if parsed is None:
            parsed = _marlin_parse(text)
            if len(self._parsed) < _PARSE_CACHE_LINES:
                self._parsed[text] = parsed
        self.queue.append((number, text, parsed[0], parsed[1], raw))

    def _corrupt(self, raw: bytes) -> bytes:
        # never the leading 'N': a line that loses it is taken unnumbered, a hole in Marlin's protocol
        start = 1 if raw.startswith(b"N") else 0
        if len(raw) <= start:
            return raw
        i = int(self.rng.integers(start, len(raw)))
        choices = [c for c in b"0123456789ABCDEFGXYZ .-" if c != raw[i]]
        return raw[:i] + bytes([choices[int(self.rng.integers(len(choices)))]]) + raw[i + 1 :]

    def _line_error(self, message: str) -> None:
        self._emit(f"Error:{message}{self.last_n}")
        self._request_resend()

    def _request_resend(self) -> None:
        """queue.cpp flush_and_request_resend (after a line error, and M999's): the RX buffer emptied, then
        `Resend: <last N + 1>` and a bare `ok`, even with ADVANCED_OK."""
        self.rx.clear()
        self._emit(f"{R.RESEND}{self.last_n + 1}")
        if self.ok_after_resend:
            self._emit(R.OK, is_ok=True)


def _marlin_parse(text: str) -> tuple[str, GcodeLine | None]:
    """(code, parsed line) as stock Marlin's parser reads a command: the letter G, M or T in upper case and a
    number, or it is unknown (code ""); a parameter is an upper-case letter, so `y7` is no parameter and is
    ignored (free text, M117/M118's, is kept as it came)."""
    if _COMMAND.match(text) is None:
        return "", None
    code_end = text.find(" ")
    code_text = text if code_end < 0 else text[:code_end]
    if code_end >= 0 and code_text not in TEXT_COMMANDS and any(c.islower() for c in text):
        text = " ".join([code_text] + [word for word in text[code_end:].split() if not word[0].islower()])
    try:
        line = parse_line(text)
    except ConfigError:
        line = None
    if line is not None and code_text in TEXT_COMMANDS and text[-1:] == " ":  # Marlin keeps the text's spaces
        line = dataclasses.replace(line, params={**line.params, "text": line.text + text[len(text.rstrip(" ")) :]})
    if line is not None:  # strtof: the firmware's positions are 32-bit (the parse is new: its params are its own)
        params = line.params
        for axis in _AXES:
            value = params.get(axis)
            if isinstance(value, float):
                params[axis] = f32(value)
    return (line.code if line is not None else code_text, line)

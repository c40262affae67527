"""What the driver accepts as a command: comments dropped, framing refused, each distinct line parsed once.

`clean_command` checks one command for `MarlinDriver.send`; `CommandParser.parse_batch` parses a
program for `send_lines` with one GcodeSyntaxError listing every bad line. A campaign sends the
same lines press after press (`M400`, the descend and lift moves), so the parser keeps the parse
of each distinct text (GcodeLine is immutable) in a bounded cache: the repeated lines come first.
"""

from __future__ import annotations

from collections.abc import Iterable

from neatskin.errors import Problem
from neatskin.gcode.parse import GcodeLine, GcodeSyntaxError, parse_line

PARSE_CACHE_LINES = 1024  # distinct lines kept parsed per driver


class CommandParser:
    """parse_program and `clean_command` for send_lines' batches, with a bounded cache of parses."""

    def __init__(self, cache_lines: int = PARSE_CACHE_LINES) -> None:
        self.cache_lines = cache_lines
        self._parsed: dict[str, tuple[str, GcodeLine | None]] = {}

    def parse_batch(self, lines: Iterable[str], source: str) -> list[tuple[str, GcodeLine]]:
        """(command, parsed line) of every command, blank and comment-only lines dropped. Raises one
        GcodeSyntaxError listing every bad line (named by source and line number), then ValueError for
        a line framed with N.. or *.. (the driver adds the framing itself)."""
        cache = self._parsed
        out: list[tuple[str, GcodeLine]] = []
        problems: list[Problem] = []
        framed: ValueError | None = None
        for number, text in enumerate("\n".join(lines).splitlines(), start=1):
            hit = cache.get(text)
            if hit is None:
                try:
                    parsed = parse_line(text, source=source, line_no=number)
                    hit = (clean_parsed(parsed), parsed) if parsed is not None else ("", None)
                except GcodeSyntaxError as exc:
                    problems.extend(exc.problems)
                    continue
                except ValueError as exc:  # framing: reported after every syntax error
                    framed = framed or exc
                    continue
                if len(cache) < self.cache_lines:
                    cache[text] = hit
            command, line = hit
            if line is not None:
                out.append((command, line))
        if problems:
            raise GcodeSyntaxError(problems=problems)
        if framed is not None:
            raise framed
        return out


def clean_parsed(line: GcodeLine) -> str:
    """`clean_command` for a line parsed already (the same checks, without parsing it again)."""
    if line.line_number is not None or line.checksum is not None:
        raise ValueError(f"send commands without N.. or *.. framing (the driver adds it), got {line.raw!r}")
    return line.raw.split(";", 1)[0].strip()


def clean_command(command: str) -> str:
    """Drop a comment and surrounding blanks; refuse framing the driver adds itself."""
    text = command.split(";", 1)[0].strip()
    if "\n" in text or "\r" in text:
        raise ValueError(f"one command per call, got {command!r}")
    parsed = parse_line(text) if text else None
    if parsed is not None and (parsed.line_number is not None or parsed.checksum is not None):
        raise ValueError(f"send commands without N.. or *.. framing (the driver adds it), got {command!r}")
    return text

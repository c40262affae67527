"""`TableReader`: typed reading of one TOML table, key by key (kept for sim/scene.py; new code declares a schema)."""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any

from neatskin.errors import Problem


@dataclass
class TableReader:
    """Reads keys from one TOML table, recording a Problem for each bad or unknown key."""

    table: dict
    section: str
    source: str
    problems: list[Problem] = field(default_factory=list)
    _seen: set[str] = field(default_factory=set)

    def _problem(self, key: str, message: str, fix: str) -> None:
        self.problems.append(Problem(message, self.source, f"{self.section}.{key}", fix))

    def _get(self, key: str, default: Any) -> Any:
        self._seen.add(key)
        return self.table.get(key, default)

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        minimum: float | None = None,
        maximum: float | None = None,
        positive: bool = False,
        unit: str = "",
    ) -> float | None:
        value = self._get(key, default)
        hint = f"set {key} to a number{' in ' + unit if unit else ''}"
        if value is None:
            self._problem(key, f"missing '{key}'", hint)
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self._problem(key, f"'{key}' must be a finite number, got {value!r}", hint)
            return None
        if positive and value <= 0:
            self._problem(key, f"'{key}' must be positive, got {value!r}", f"set {key} > 0")
            return None
        if minimum is not None and value < minimum:
            self._problem(key, f"'{key}' = {value!r} is below {minimum}", f"set {key} >= {minimum}")
            return None
        if maximum is not None and value > maximum:
            self._problem(key, f"'{key}' = {value!r} is above {maximum}", f"set {key} <= {maximum}")
            return None
        return float(value)

    def integer(self, key: str, default: int | None = None, *, minimum: int | None = None) -> int | None:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            self._problem(key, f"'{key}' must be an integer, got {value!r}", f"set {key} to a whole number")
            return None
        if minimum is not None and value < minimum:
            self._problem(key, f"'{key}' = {value} is below {minimum}", f"set {key} >= {minimum}")
            return None
        return value

    def boolean(self, key: str, default: bool | None = None) -> bool | None:
        value = self._get(key, default)
        if not isinstance(value, bool):
            self._problem(key, f"'{key}' must be true or false, got {value!r}", f"set {key} = true or false")
            return None
        return value

    def choice(self, key: str, options: tuple[str, ...], default: str | None = None) -> str | None:
        value = self._get(key, default)
        if value not in options:
            self._problem(
                key,
                f"'{key}' = {value!r} is not one of {', '.join(options)}",
                f"set {key} to one of: {', '.join(repr(o) for o in options)}",
            )
            return None
        return value

    def text(self, key: str, default: str | None = None) -> str | None:
        value = self._get(key, default)
        if not isinstance(value, str) or not value:
            self._problem(key, f"'{key}' must be a non-empty string, got {value!r}", f"set {key} to a name")
            return None
        return value

    def check_unknown(self) -> None:
        for key in self.table:
            if key not in self._seen:
                close = difflib.get_close_matches(key, sorted(self._seen), n=1)
                fix = (
                    f"did you mean '{close[0]}'?"
                    if close
                    else f"remove it; known keys: {', '.join(sorted(self._seen))}"
                )
                self._problem(key, f"unknown key '{key}'", fix)

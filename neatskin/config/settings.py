"""Validation at construction: a settings table refuses a bad value when it is built, with the file's own text.

A table of settings is a frozen dataclass deriving from `Settings` whose fields are declared with
`schema.setting(...)`. Built from a file (`schema.parse`) or in Python (`PressSpec(depth_mm=5000)`),
each value goes through the same checks of the same declaration, so the message is the one the file
schema gives and a value the file refuses cannot exist in memory. A subclass adds what spans several
of its keys in `cross_problems` (key, message, fix). Values are normalised as the file reader
normalises them: an int for a float becomes a float, a list for a tuple a tuple.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from neatskin.config.declare import Constraint, constraint_of, hints, is_setting
from neatskin.config.schema import check_value
from neatskin.errors import ConfigError, Problem


class Settings:
    """Base of every settings table: checks each `setting` field, then `cross_problems`, at construction."""

    TOML_TABLE: ClassVar[str] = ""  # where the table sits in its file, for the errors of one built in Python

    def __post_init__(self) -> None:
        source = getattr(self, "source", None)
        problems: list[Problem] = []
        for name, tp, constraint, where in _declared(type(self)):
            value = getattr(self, name)
            good, normalised, found = check_value(tp, value, constraint, name, where, source)
            problems += found
            if good and normalised is not value:
                object.__setattr__(self, name, normalised)
        if not problems:
            for key, message, fix in self.cross_problems():
                where = f"{self.TOML_TABLE}.{key}" if self.TOML_TABLE else key
                problems.append(Problem(message, source, where, fix))
        if problems:
            raise ConfigError(problems=problems)

    def cross_problems(self) -> list[tuple[str, str, str]]:
        """What spans several keys of this table: (key, message, fix) for each problem; none by default."""
        return []


_DECLARED: dict[type, tuple[tuple[str, Any, Constraint, str], ...]] = {}


def _declared(cls: type) -> tuple[tuple[str, Any, Constraint, str], ...]:
    """(name, type, constraint, where) of each setting field of a class, worked out once per class."""
    found = _DECLARED.get(cls)
    if found is None:
        table = getattr(cls, "TOML_TABLE", "")
        types_ = hints(cls)
        found = _DECLARED[cls] = tuple(
            (f.name, types_[f.name], constraint_of(f), f"{table}.{f.name}" if table else f.name)
            for f in dataclasses.fields(cls)
            if is_setting(f)
        )
    return found

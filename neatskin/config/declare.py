"""Declaring a schema: `setting(...)` and the `Constraint` it carries, and reading the declarations back.

A schema is a frozen dataclass whose fields are declared with `setting(default, unit=..., ge=...,
doc=...)`; this module owns that vocabulary and the questions every other part asks of it (which
fields are keys of the file, under which TOML key, which are required, their resolved types, a
constraint in words). The engine that reads a TOML table against a schema is `schema`; the
reference generated from the declarations is `docs`.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import MISSING, dataclass
from typing import Any

_META = "neatskin.setting"
_NOT_A_KEY = "neatskin.not_a_key"


@dataclass(frozen=True)
class Constraint:
    """What one setting accepts: unit, range, choices, pattern, and the sentence that documents it."""

    unit: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[str, ...] = ()
    pattern: str | None = None
    pattern_text: str = ""  # the pattern in words, for the error and the docs
    max_len: int | None = None
    min_items: int = 0
    allow_empty: bool = False  # text may be ""
    one_or_list: bool = False  # a list may be written as its one value (pitch_mm = 15.0 for [15.0])
    doc: str = ""
    example: str = ""  # a value to put in the fix when the key is missing
    default_doc: str = ""  # how a derived default (None in the schema) is computed


_NO_CONSTRAINT = Constraint()


def setting(default: Any = MISSING, *, key: str | None = None, **constraint: Any) -> Any:
    """A schema field: its default (none = required), its TOML key if not the field's name, its `Constraint`."""
    meta: dict[str, Any] = {_META: Constraint(**constraint)}
    if key is not None:
        meta["key"] = key
    if isinstance(default, (list, dict, set)):
        raise TypeError("use a tuple (immutable) default")
    return dataclasses.field(default=default, metadata=meta)


def source_field() -> Any:
    """A field that is not a key of the file: the file a value was read from (set by the engine), for its errors."""
    return dataclasses.field(default="<memory>", compare=False, metadata={_NOT_A_KEY: True})


def key_fields(schema: type) -> tuple[dataclasses.Field, ...]:
    """The fields that are keys of the file (a `source_field` is not)."""
    return tuple(f for f in dataclasses.fields(schema) if not f.metadata.get(_NOT_A_KEY))


def is_setting(f: dataclasses.Field) -> bool:
    return _META in f.metadata


def constraint_of(f: dataclasses.Field) -> Constraint:
    return f.metadata.get(_META, _NO_CONSTRAINT)


def is_schema(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


_HINTS: dict[type, dict[str, Any]] = {}


def hints(schema: type) -> dict[str, Any]:
    """The field types of a schema (resolved once per class: every construction checks its fields)."""
    found = _HINTS.get(schema)
    if found is None:
        found = _HINTS[schema] = typing.get_type_hints(schema)
    return found


def toml_key(f: dataclasses.Field) -> str:
    """The key in the file: the field name, or metadata `key` (for TOML keys that are Python keywords)."""
    return f.metadata.get("key", f.name)


def is_required(f: dataclasses.Field) -> bool:
    return f.default is MISSING and f.default_factory is MISSING


def describe_range(c: Constraint) -> str:
    """The constraint in words, e.g. '> 0, <= 0.1'."""
    parts = []
    for op, bound in ((">", c.gt), (">=", c.ge), ("<", c.lt), ("<=", c.le)):
        if bound is not None:
            parts.append(f"{op} {bound:g}")
    if c.choices:
        parts.append("one of " + ", ".join(repr(x) for x in c.choices))
    if c.pattern_text:
        parts.append(c.pattern_text)
    if c.max_len is not None:
        parts.append(f"at most {c.max_len} characters")
    if c.min_items:
        parts.append(f"at least {c.min_items} " + ("entry" if c.min_items == 1 else "entries"))
    if c.one_or_list:
        parts.append("one value for a list of one")
    return ", ".join(parts)

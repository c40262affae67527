"""The declarative config engine: reading a TOML table against its schema, with every problem's text and fix.

A schema is a frozen dataclass; each field is declared with `setting(...)` (default, unit, range,
choices, pattern, doc: `declare`) or is itself a schema (a TOML table), a tuple of schemas (an array of
tables), a tuple of numbers, or a free `dict[str, X]` table. `parse(Schema, data, source)` walks
the data once and collects every problem (wrong type, out of range, missing, unknown key at any
level with a difflib "did you mean") as a `Problem` naming file, field and fix; it returns the
fully typed instance only when there is none. One declaration per setting gives validation,
default, documentation (`neatskin.config.docs`) and the error text, in the spirit of
scikit-learn's `_parameter_constraints`; no dependency beyond the standard library.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING
from typing import Any, TypeVar, Union

from neatskin.config.declare import (
    Constraint,
    constraint_of,
    describe_range,
    hints,
    is_required,
    is_schema,
    key_fields,
    toml_key,
)
from neatskin.errors import ConfigError, Problem

T = TypeVar("T")


class _Walker:
    """One parse: the source file and the problems found so far."""

    def __init__(self, source: str | None) -> None:
        self.source = source
        self.problems: list[Problem] = []

    def problem(self, where: str, message: str, fix: str) -> None:
        self.problems.append(Problem(message, self.source, where or None, fix))

    # ---- tables ----------------------------------------------------------------------

    def table(self, schema: type, data: Any, where: str, partial: bool = False, valid: bool = False) -> Any:
        """An instance of `schema` from a TOML table, or None after recording its problems.

        partial: keys that are absent are left out (the result is a dict of the keys present);
        valid: the result is a dict of every field that is good (defaults included), bad ones left out."""
        if not isinstance(data, Mapping):
            self.not_a_table(data, where)
            return None
        fields = key_fields(schema)
        by_key = {toml_key(f): f for f in fields}
        types_ = hints(schema)
        if not where and not data and any(is_required(f) for f in fields):
            self.problem("", "the file is empty", f"write its tables ({_key_list(schema, required=True)})")
            return {} if (valid or partial) else None
        # a misspelt key ("nme", "[campain]") is one mistake: its "did you mean" stands for the missing key too
        suggested = self.unknown_keys(data, tuple(by_key), where)
        values: dict[str, Any] = {}
        ok = True
        for key, f in by_key.items():
            here = f"{where}.{key}" if where else key
            tp = types_[f.name]
            if key not in data:
                if partial:
                    continue
                if valid and not is_required(f):
                    values[f.name] = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc,operator]
                    continue
                if is_required(f) and key in suggested:
                    ok = False
                elif is_required(f):
                    if is_schema(tp):
                        self.problem(
                            here, f"missing [{here}] table", f"add a [{here}] table with {_key_list(tp, required=True)}"
                        )
                    else:
                        self.problem(here, f"missing '{key}'", _fix(key, constraint_of(f), tp))
                    ok = False
                continue
            value, good = self.value(tp, data[key], here, constraint_of(f), key)
            ok = ok and good
            if good or not valid:
                values[f.name] = value
        if valid:
            return values
        if partial:
            return values if ok else None
        return self.construct(schema, values, where) if ok else None

    def construct(self, schema: type, values: dict[str, Any], where: str) -> Any:
        """The instance; the checks its type makes at construction (across its keys) become problems here."""
        if "source" in {f.name for f in dataclasses.fields(schema)} and "source" not in values:
            values = {**values, "source": self.source}
        try:
            return schema(**values)
        except ConfigError as exc:
            own = getattr(schema, "TOML_TABLE", "")
            for p in exc.problems:
                field = p.field or ""
                if own and (field == own or field.startswith(own + ".")):
                    field = field[len(own) + 1 :]
                self.problem(f"{where}.{field}" if where and field else (where or field), p.message, p.fix or "")
            return None

    def not_a_table(self, data: Any, where: str) -> None:
        if isinstance(data, list) and data and all(isinstance(item, Mapping) for item in data):
            self.problem(
                where,
                f"[{where}] is written as an array of tables [[{where}]], but it is one table",
                f"write its header with single brackets: [{where}]",
            )
            return
        shown = _short_repr(data)
        self.problem(where, f"[{where}] must be a table, got {shown}", f"write it as [{where}] with its keys")

    def unknown_keys(self, data: Mapping, known: tuple[str, ...], where: str) -> set[str]:
        """Record a problem per unknown key; return the known keys suggested for them (not to be reported missing)."""
        suggested: set[str] = set()
        for key in data:
            if key in known:
                continue
            here = f"{where}.{key}" if where else key
            close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
            value = data[key]
            is_table = isinstance(value, Mapping) or (
                isinstance(value, list) and bool(value) and all(isinstance(item, Mapping) for item in value)
            )
            kind = "table" if is_table else "key"
            shown = f"[{here}]" if kind == "table" else f"'{key}'"
            if close and close[0] not in data:
                suggested.add(close[0])
                fix = f"did you mean '{close[0]}'?"
            elif close:
                fix = f"did you mean '{close[0]}'?"
            else:
                fix = f"remove it; known: {', '.join(known) or '(none)'}"
            self.problem(here, f"unknown {kind} {shown}", fix)
        return suggested

    # ---- values ----------------------------------------------------------------------

    def value(self, tp: Any, value: Any, where: str, c: Constraint, key: str) -> tuple[Any, bool]:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (Union, types.UnionType):  # X | None: TOML has no null, so a present value is an X
            inner = [a for a in args if a is not type(None)]
            return self.value(inner[0], value, where, c, key)
        if is_schema(tp) and isinstance(value, tp):  # built in Python, so checked at its construction
            return value, True
        if is_schema(tp):
            result = self.table(tp, value, where)
            return result, result is not None
        if origin is tuple:
            return self.sequence(args, value, where, c, key)
        if origin is dict:
            return self.mapping(args[1], value, where, c, key)
        if tp is Any:
            return value, True
        return self.scalar(tp, value, where, c, key)

    def sequence(self, args: tuple, value: Any, where: str, c: Constraint, key: str) -> tuple[Any, bool]:
        if c.one_or_list and not isinstance(value, (list, tuple)) and len(args) == 2 and args[1] is Ellipsis:
            value = [value]
        if not isinstance(value, (list, tuple)):  # a TOML array is a list; a value built in Python holds tuples
            self.problem(where, f"'{key}' must be a list, got {value!r}", _fix(key, c, tuple))
            return None, False
        if len(args) == 2 and args[1] is Ellipsis:
            item_types = [args[0]] * len(value)
            if typing.get_origin(args[0]) is tuple and value and not any(isinstance(v, (list, tuple)) for v in value):
                # sizes = [3, 3] for [[3, 3]]: one problem for the list, not one per number
                self.problem(where, f"'{key}' is a list of lists, got {_short_repr(value)}", _fix(key, c, tuple))
                return None, False
        else:
            item_types = list(args)
            if len(value) != len(args):
                self.problem(where, f"'{key}' needs {len(args)} items, got {len(value)}", _fix(key, c, tuple))
                return None, False
        if len(value) < c.min_items:
            entries = "entry" if c.min_items == 1 else "entries"
            self.problem(
                where, f"'{key}' needs at least {c.min_items} {entries}, got {len(value)}", _fix(key, c, tuple)
            )
            return None, False
        items, ok = [], True
        for k, (item_tp, item) in enumerate(zip(item_types, value)):
            item_c = dataclasses.replace(c, min_items=0, one_or_list=False)
            got, good = self.value(item_tp, item, f"{where}[{k}]", item_c, key)
            items.append(got)
            ok = ok and good
        return tuple(items), ok

    def mapping(self, item_tp: Any, value: Any, where: str, c: Constraint, key: str) -> tuple[Any, bool]:
        if not isinstance(value, Mapping):
            self.problem(where, f"'{key}' must be a table, got {value!r}", _fix(key, c, dict))
            return None, False
        out, ok = {}, True
        for k, item in value.items():
            got, good = self.value(item_tp, item, f"{where}.{k}", c, str(k))
            out[str(k)] = got
            ok = ok and good
        return out, ok

    def scalar(self, tp: Any, value: Any, where: str, c: Constraint, key: str) -> tuple[Any, bool]:
        fix = _LazyFix(key, c, tp)  # formatted only for a problem: every construction checks
        if tp is bool:
            if not isinstance(value, bool):
                self.problem(where, f"'{key}' must be true or false, got {value!r}", f"set {key} = true or false")
                return None, False
            return value, True
        if tp is str:
            if not isinstance(value, str) or not (value or c.allow_empty):
                self.problem(where, f"'{key}' must be a non-empty string, got {value!r}", str(fix))
                return None, False
            if c.max_len is not None and len(value) > c.max_len:
                self.problem(where, f"'{key}' is {len(value)} characters long, more than {c.max_len}", str(fix))
                return None, False
            if c.choices and value not in c.choices:
                close = difflib.get_close_matches(value, c.choices, n=1)
                self.problem(
                    where,
                    f"'{key}' = {value!r} is not one of {', '.join(c.choices)}",
                    (f"did you mean {close[0]!r}? " if close else "") + str(fix),
                )
                return None, False
            if c.pattern is not None and not re.fullmatch(c.pattern, value):
                self.problem(where, f"'{key}' = {value!r} is not {c.pattern_text or 'allowed'}", str(fix))
                return None, False
            return value, True
        if tp is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.problem(where, f"'{key}' must be an integer, got {value!r}", str(fix))
                return None, False
        elif tp is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                self.problem(where, f"'{key}' must be a finite number, got {value!r}", str(fix))
                return None, False
            value = float(value)
        else:  # pragma: no cover - a schema declared with a type the engine does not know
            raise TypeError(f"unsupported schema type {tp!r} at {where}")
        bad = _range_violation(value, c)
        if bad:
            self.problem(where, f"'{key}' = {value!r} {bad}", str(fix))
            return None, False
        return value, True


class _LazyFix:
    """The fix text of a value, formatted when a problem asks for it."""

    __slots__ = ("key", "c", "tp")

    def __init__(self, key: str, c: Constraint, tp: Any) -> None:
        self.key, self.c, self.tp = key, c, tp

    def __str__(self) -> str:
        return _fix(self.key, self.c, self.tp)


def _short_repr(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 20]}...{text[-12:]} (a {type(value).__name__})"


def _range_violation(value: float, c: Constraint) -> str:
    if c.gt is not None and not value > c.gt:
        return "must be positive" if c.gt == 0 else f"must be above {c.gt:g}"
    if c.ge is not None and not value >= c.ge:
        return f"is below {c.ge:g}"
    if c.lt is not None and not value < c.lt:
        return f"must be below {c.lt:g}"
    if c.le is not None and not value <= c.le:
        return f"is above {c.le:g}"
    return ""


def _fix(key: str, c: Constraint, tp: Any) -> str:
    kind = {bool: "true or false", int: "a whole number", float: "a number", str: "text", tuple: "a list"}.get(
        tp, "a value"
    )
    rng = describe_range(c)
    text = f"set {key} to {kind}" + (f" in {c.unit}" if c.unit else "") + (f" ({rng})" if rng else "")
    if c.example:
        text += f", e.g. {key} = {c.example}"
    return text


def _key_list(schema: type, required: bool = False) -> str:
    keys = [toml_key(f) for f in key_fields(schema) if is_required(f) or not required]
    return ", ".join(keys) if keys else "its keys"


def check_value(
    tp: Any, value: Any, c: Constraint, key: str, where: str, source: str | None
) -> tuple[bool, Any, list[Problem]]:
    """One value built in Python against its declaration, as the file reader checks it: good, normalised, problems."""
    if value is None and type(None) in typing.get_args(tp):
        return True, None, []
    walker = _Walker(source)
    got, good = walker.value(tp, value, where, c, key)
    return good, got, walker.problems


def build(schema: type[T], values: dict[str, Any], source: str, where: str = "") -> tuple[T | None, list[Problem]]:
    """The instance built from values already read (None if its construction refuses them) and the problems."""
    walker = _Walker(source)
    result = walker.construct(schema, values, where)
    return result, walker.problems


def parse_collect(schema: type[T], data: Any, source: str, where: str = "") -> tuple[T | None, list[Problem]]:
    """The instance (None if anything is wrong) and every problem found; for loaders that merge problems."""
    walker = _Walker(source)
    result = walker.table(schema, data, where)
    return (result if not walker.problems else None), walker.problems


def parse(schema: type[T], data: Any, source: str, where: str = "") -> T:
    """The fully typed instance of `schema` read from `data`; one ConfigError with every problem otherwise."""
    result, problems = parse_collect(schema, data, source, where)
    if problems or result is None:
        raise ConfigError(problems=problems or [Problem("no value", source, where or None, "check the file")])
    return result


def parse_partial(schema: type, data: Any, source: str, where: str = "") -> tuple[dict[str, Any], list[Problem]]:
    """Only the keys present in `data`, each checked against `schema` (absent keys are no problem)."""
    walker = _Walker(source)
    result = walker.table(schema, data, where, partial=True)
    return (result or {}), walker.problems


def parse_valid(schema: type[T], data: Any, source: str, where: str = "") -> tuple[dict[str, Any], list[Problem]]:
    """The fields of one table that read cleanly (defaults for the absent ones, bad ones left out), and every problem.

    For a table whose good values still feed cross-field checks (`schema(**good)` when every field has a default)."""
    walker = _Walker(source)
    result = walker.table(schema, data, where, valid=True)
    return (result or {}), walker.problems


def unknown_key_problems(data: Mapping, known: tuple[str, ...], source: str, where: str = "") -> list[Problem]:
    """'did you mean' problems for the keys of `data` outside `known` (for tables read by hand)."""
    walker = _Walker(source)
    walker.unknown_keys(data, known, where)
    return walker.problems

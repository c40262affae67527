"""The schema engine: every problem at once, unknown keys and tables at every level with a suggestion,
defaults applied, fully typed values; and docs/config.md is what the schemas generate."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pytest

from neatskin.config import parse, parse_collect, parse_partial, parse_tables, setting
from neatskin.config.docs import render_markdown
from neatskin.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Inner:
    depth_mm: float = setting(unit="mm", gt=0, le=10)
    kind: str = setting("a", choices=("a", "b"))


@dataclass(frozen=True)
class Item:
    number: int = setting(ge=1)
    start: str = setting(key="from")


@dataclass(frozen=True)
class Outer:
    inner: Inner
    items: tuple[Item, ...] = setting(min_items=1)
    flag: bool = setting(False)
    pair: tuple[int, int] | None = setting(None, ge=0)
    ratio: float | None = setting(None, ge=0, le=1)
    note: str = setting("", allow_empty=True)


GOOD = {"inner": {"depth_mm": 2}, "items": [{"number": 1, "from": "J1"}], "pair": [1, 2]}


def test_a_good_table_gives_a_fully_typed_value_with_defaults():
    value = parse(Outer, GOOD, "f.toml")
    assert value == Outer(Inner(2.0, "a"), (Item(1, "J1"),), False, (1, 2), None, "")
    assert isinstance(value.inner.depth_mm, float)


def test_every_problem_at_once_with_file_field_and_fix():
    data = {
        "inner": {"depth_mm": math.nan, "knd": "b"},
        "items": [{"number": 0, "from": "J1"}, {"from": 3}],
        "flag": "yes",
        "pair": [1],
        "ratio": 2.0,
        "note": "",
        "extra": {"x": 1},
    }
    with pytest.raises(ConfigError) as info:
        parse(Outer, data, "f.toml")
    got = [(p.field, p.message) for p in info.value.problems]
    assert got == [
        ("extra", "unknown table [extra]"),
        ("inner.knd", "unknown key 'knd'"),
        ("inner.depth_mm", "'depth_mm' must be a finite number, got nan"),
        ("items[0].number", "'number' = 0 is below 1"),
        ("items[1].number", "missing 'number'"),
        ("items[1].from", "'from' must be a non-empty string, got 3"),
        ("flag", "'flag' must be true or false, got 'yes'"),
        ("pair", "'pair' needs 2 items, got 1"),
        ("ratio", "'ratio' = 2.0 is above 1"),
    ]
    assert all(p.file == "f.toml" and p.fix for p in info.value.problems)
    assert info.value.problems[1].fix == "did you mean 'kind'?"
    assert info.value.problems[0].fix == "remove it; known: inner, items, flag, pair, ratio, note"


def test_missing_table_and_choices():
    with pytest.raises(ConfigError) as info:
        parse(Outer, {"items": [{"number": 1, "from": "a"}], "inner": {"depth_mm": 1, "kind": "bb"}}, "f.toml")
    (problem,) = info.value.problems
    assert problem.field == "inner.kind" and problem.fix.startswith("did you mean 'b'?")
    value, problems = parse_collect(Outer, {"items": []}, "f.toml")
    assert value is None
    assert [(p.field, p.message) for p in problems] == [
        ("inner", "missing [inner] table"),
        ("items", "'items' needs at least 1 entry, got 0"),
    ]


def test_partial_and_per_table_reading():
    values, problems = parse_partial(Inner, {"kind": "b"}, "f.toml", "inner")
    assert values == {"kind": "b"} and problems == []
    tables, problems = parse_tables(Outer, {"inner": {"depth_mm": -1}, "items": [{"number": 2, "from": "x"}]}, "f")
    assert tables == {"items": (Item(2, "x"),), "flag": False, "pair": None, "ratio": None, "note": ""}
    assert [p.field for p in problems] == ["inner.depth_mm"]


def test_docs_config_md_is_generated_from_the_schemas():
    committed = (REPO / "docs" / "config.md").read_text()
    assert committed == render_markdown(), "regenerate: python -m neatskin.config.docs > docs/config.md"
    assert "| `homing_time_s` | number | s | 20.0 | > 0, <= 3600 |" in committed
    assert "### `[park]` (optional)" in committed

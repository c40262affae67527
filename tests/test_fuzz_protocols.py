"""Fuzzed protocol files: mutations of paper.toml through campaign check and G-code generation.

The only outcomes allowed are success or a NeatskinError subclass (one clear error naming file,
field and fix); a traceback of any other type, or a hang, fails the test."""

from __future__ import annotations

import json
import math
import os
import tomllib

import pytest
from conftest import PROTOCOLS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neatskin.errors import ConfigError, NeatskinError
from neatskin.gcode.spec import build_from_protocol
from neatskin.rig.protocol import load_protocol

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

PAPER = tomllib.loads((PROTOCOLS / "paper.toml").read_text())
for _key in ("layout", "wiring", "printer"):  # absolute, so the mutated copy can live anywhere
    PAPER["files"][_key] = str(PROTOCOLS / PAPER["files"][_key])
LEAVES = [(table, key) for table, values in PAPER.items() for key in values]

EXTREMES = [
    1e308,
    -1e308,
    1e15,
    -1e-308,
    0,
    -1,
    0.0,
    2**63 - 1,
    -(2**63),
    math.nan,
    math.inf,
    -math.inf,
    "",
    "smöke",
    "../../x",
    "/etc/passwd",
    "x\nG28",
    "\u2028",
    True,
    False,
    [],
    [1.0, "a"],
    {},
    {"a": 1},
]


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(value)


def toml_text(data: dict) -> str:
    out = []
    for table, values in data.items():
        if not isinstance(values, dict):
            out.append(f"{json.dumps(table)} = {toml_value(values)}")
            continue
        out.append(f"[{json.dumps(table, ensure_ascii=False)}]")
        out += [f"{json.dumps(k, ensure_ascii=False)} = {toml_value(v)}" for k, v in values.items()]
    return "\n".join(out) + "\n"


def test_the_writer_round_trips_paper_toml():
    assert tomllib.loads(toml_text(PAPER)) == PAPER


mutation = st.one_of(
    st.tuples(st.just("replace"), st.sampled_from(LEAVES), st.sampled_from(EXTREMES)),
    st.tuples(st.just("replace"), st.sampled_from(LEAVES), st.text(max_size=12)),
    st.tuples(st.just("delete"), st.sampled_from(LEAVES), st.none()),
    st.tuples(st.just("unknown"), st.sampled_from(LEAVES), st.text(min_size=1, max_size=8)),
    st.tuples(st.just("drop_table"), st.sampled_from(LEAVES), st.none()),
)


def mutate(data: dict, mutations) -> dict:
    data = json.loads(json.dumps(data, allow_nan=True))
    for action, (table, key), value in mutations:
        if table not in data:
            continue
        if action == "replace":
            data[table][key] = value
        elif action == "delete":
            data[table].pop(key, None)
        elif action == "unknown":
            data[table][key + value] = 1.0
        else:
            del data[table]
    return data


@settings(
    max_examples=int(os.environ.get("NEATSKIN_FUZZ_EXAMPLES", "30")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(mutations=st.lists(mutation, min_size=1, max_size=3))
def test_fuzzed_protocols_succeed_or_raise_a_neatskin_error(tmp_path, mutations):
    path = tmp_path / "fuzzed.toml"
    path.write_text(toml_text(mutate(PAPER, mutations)), encoding="utf-8")
    try:
        load_protocol(path)
    except NeatskinError as exc:
        assert isinstance(exc, ConfigError) and exc.problems and all(p.fix for p in exc.problems)
    try:  # what `neatskin gcode generate` does
        program, _, _ = build_from_protocol(path)
        program.text().encode("ascii")
    except NeatskinError:
        pass


def test_an_unmutated_copy_passes(tmp_path):
    path = tmp_path / "copy.toml"
    path.write_text(toml_text(PAPER))
    assert load_protocol(path).name == "paper"


@pytest.mark.parametrize(
    "mutations, field",
    [
        ([("replace", ("press", "hold_s"), 1e15)], "press.hold_s"),
        ([("replace", ("campaign", "name"), "smöke")], "campaign.name"),
        ([("replace", ("scene", "surface_error_mm"), -1e308)], "scene.surface_error_mm"),
        ([("unknown", ("press", "depth_mm"), "x")], "press.depth_mmx"),
        ([("drop_table", ("excitation", "amplitude_a"), None)], "excitation"),
    ],
)
def test_known_crashers_are_one_named_error(tmp_path, mutations, field):
    # each of these passed campaign check or ended in a traceback before (issue 10)
    path = tmp_path / "fuzzed.toml"
    path.write_text(toml_text(mutate(PAPER, mutations)))
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert [p.field for p in info.value.problems] == [field]

"""One declaration per setting: the tables a file is read into are the values the code uses, checked at
construction with the file schema's own text, so a value the file refuses cannot exist in memory."""

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.config import parse_collect
from neatskin.config.declare import constraint_of, is_required, key_fields
from neatskin.config.files import AcquisitionSettings, Excitation, PositionSpec, PressSpec
from neatskin.config.printerfile import PrinterTable
from neatskin.config.scene import PRESET_DEFORMATION, PRESETS, SCENE_KNOBS, Scene
from neatskin.errors import ConfigError
from neatskin.gcode.profile import load_printer_profile

SIX = (PressSpec, PositionSpec, Scene, Excitation, AcquisitionSettings, PrinterTable)
REQUIRED = {
    PressSpec: {"depth_mm": 3.5, "repeats": 2},
    PositionSpec: {"strategy": "paper", "count": 10},
    Scene: {},
    Excitation: {"amplitude_a": 0.0005, "frequency_hz": 1000.0},
    AcquisitionSettings: {
        "rate_hz": 10_000.0,
        "settle_samples": 20,
        "live_samples": 100,
        "demodulation": "rms",
        "window": 50,
    },
    PrinterTable: {},
}


def shown(problems):
    return [(p.field, p.message, p.fix) for p in problems]


def refusal(build):
    with pytest.raises(ConfigError) as err:
        build()
    return err.value.problems


def test_press_values_the_file_refuses_are_refused_in_python_with_the_same_text():
    bad = {"depth_mm": 5000, "probe_diameter_mm": 0, "repeats": 10**7}
    _, from_file = parse_collect(PressSpec, bad, "p.toml", "press")
    from_python = refusal(lambda: PressSpec(**bad))
    assert (
        shown(from_python)
        == shown(from_file)
        == [
            (
                "press.depth_mm",
                "'depth_mm' = 5000.0 is above 1000",
                "set depth_mm to a number in mm (>= 0, <= 1000), e.g. depth_mm = 3.5",
            ),
            (
                "press.repeats",
                "'repeats' = 10000000 is above 10000",
                "set repeats to a whole number (>= 1, <= 10000), e.g. repeats = 28",
            ),
            (
                "press.probe_diameter_mm",
                "'probe_diameter_mm' = 0.0 must be positive",
                "set probe_diameter_mm to a number in mm (> 0, <= 100)",
            ),
        ]
    )
    assert {p.file for p in from_file} == {"p.toml"} and {p.file for p in from_python} == {"<memory>"}
    assert shown(refusal(lambda: PressSpec(depth_mm=-5.0, repeats=0))) == [
        (
            "press.depth_mm",
            "'depth_mm' = -5.0 is below 0",
            "set depth_mm to a number in mm (>= 0, <= 1000), e.g. depth_mm = 3.5",
        ),
        (
            "press.repeats",
            "'repeats' = 0 is below 1",
            "set repeats to a whole number (>= 1, <= 10000), e.g. repeats = 28",
        ),
    ]


def test_a_billion_positions_and_a_bad_cross_key_value_are_refused_at_construction():
    _, from_file = parse_collect(PositionSpec, {"strategy": "paper", "count": 10**9}, "p.toml", "positions")
    assert (
        shown(refusal(lambda: PositionSpec(strategy="paper", count=10**9)))
        == shown(from_file)
        == [
            (
                "positions.count",
                "'count' = 1000000000 is above 100000",
                "set count to a whole number (>= 1, <= 100000), e.g. count = 100",
            )
        ]
    )
    assert [p.field for p in refusal(lambda: PositionSpec(strategy="grid", count=10))] == ["positions.grid_shape"]
    assert [p.field for p in refusal(lambda: PositionSpec("paper", 5, keep_out=((1.0, 2.0, 0.0),)))] == [
        "positions.keep_out[0]"
    ]
    assert [
        p.field for p in refusal(lambda: PressSpec(depth_mm=1.0, repeats=1, order="shuffled", travel_ordering=True))
    ] == ["press.travel_ordering"]
    assert [p.field for p in refusal(lambda: AcquisitionSettings(1e4, 20, 100, "rms", window=200))] == [
        "acquisition.window"
    ]


def test_python_values_are_normalised_as_the_file_reader_normalises_them():
    spec = PositionSpec("paper", 5, 1, min_spacing_mm=1, keep_out=[[1, 2, 3]])  # type: ignore[arg-type]
    assert spec.min_spacing_mm == 1.0 and isinstance(spec.min_spacing_mm, float)
    assert spec.keep_out == ((1.0, 2.0, 3.0),)
    assert (
        spec
        == parse_collect(
            PositionSpec,
            {"strategy": "paper", "count": 5, "seed": 1, "min_spacing_mm": 1, "keep_out": [[1, 2, 3]]},
            "f",
        )[0]
    )


@pytest.mark.parametrize("kind", SIX, ids=lambda k: k.__name__)
def test_defaults_agree_between_the_file_and_python_for_every_field(kind):
    from_file, problems = parse_collect(kind, dict(REQUIRED[kind]), "f.toml")
    assert problems == []
    from_python = kind(**REQUIRED[kind])
    assert from_file == from_python
    for f in key_fields(kind):
        if is_required(f):
            assert f.name in REQUIRED[kind]
            continue
        expected = PRESETS["ideal"][f.name] if kind is Scene and f.name in SCENE_KNOBS else f.default
        if kind is Scene and f.name == "deformation":  # "auto" resolves to the preset's pinch at construction
            expected = PRESET_DEFORMATION["ideal"]
        assert getattr(from_file, f.name) == getattr(from_python, f.name) == expected, f.name


def test_the_printer_profile_checks_the_printer_tables_settings_at_construction():
    profile = load_printer_profile("protocols/printers/paper.toml")
    assert shown(refusal(lambda: dataclasses.replace(profile, baud_rate=0))) == [
        ("printer.baud_rate", "'baud_rate' = 0 must be positive", "set baud_rate to a whole number (> 0, <= 1e+07)")
    ]
    assert dataclasses.replace(profile, name=None).printer_name == "paper"  # the file's stem, as the file reader


def _values(f):
    """Values for one field: inside and outside its range, of its type and of others."""
    c = constraint_of(f)
    out = [] if is_required(f) else [None]  # a required key left out is Python's TypeError, not a value
    out += ["text", True, -1, 0, 1, 2.5, -1e9, 1e12, math.nan, [1.0]]
    out += [b for b in (c.ge, c.gt, c.le, c.lt) if b is not None]
    out += list(c.choices)
    return st.sampled_from(out)


@pytest.mark.parametrize("kind", SIX, ids=lambda k: k.__name__)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_constructs_if_and_only_if_the_file_schema_accepts(kind, data):
    fields = key_fields(kind)
    values = dict(REQUIRED[kind])
    for f in data.draw(st.lists(st.sampled_from(fields), max_size=3, unique_by=lambda f: f.name)):
        values[f.name] = data.draw(_values(f))
    toml = {k: v for k, v in values.items() if v is not None}  # TOML has no null: a key left out
    parsed, from_file = parse_collect(kind, toml, "f.toml", kind.TOML_TABLE)
    try:
        built = kind(**toml)
    except ConfigError as exc:
        assert shown(exc.problems) == shown(from_file) != []
    else:
        assert from_file == [] and built == parsed


@pytest.mark.parametrize("bad", [[1.0], {"a": 1}, 3])
def test_a_scene_preset_that_is_not_text_is_one_config_error_as_in_the_file(bad):
    # a list preset once escaped as TypeError (unhashable) from the preset lookup, before the schema's check
    _, from_file = parse_collect(Scene, {"preset": bad}, "f.toml", Scene.TOML_TABLE)
    with pytest.raises(ConfigError) as caught:
        Scene(preset=bad)
    assert shown(caught.value.problems) == shown(from_file)
    assert len(from_file) == 1 and "preset" in str(caught.value)

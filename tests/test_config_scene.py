"""The protocol's [scene] on the config schema: one declaration of its keys (neatskin.config.scene.Scene, the
schema and the value at once), the presets' values filling the knobs left out, and the schema's error texts."""

import dataclasses

import pytest

from neatskin.config import parse_tables
from neatskin.config.files import ProtocolFile
from neatskin.config.scene import SCENE_KNOBS, SCENE_PRESETS
from neatskin.errors import ConfigError
from neatskin.sim.scene import PAPER_LIKE, PRESETS, Scene, parse_scene


def test_the_schema_declares_every_scene_field_and_the_presets_set_every_knob():
    assert ProtocolFile.__dataclass_fields__["scene"].type in ("Scene", Scene)  # the schema's table is the value
    assert tuple(PRESETS) == SCENE_PRESETS
    assert all(set(values) == set(SCENE_KNOBS) for values in PRESETS.values())
    assert len(SCENE_KNOBS) == 13 and "surface_error_mm" not in SCENE_KNOBS


def test_an_empty_scene_is_the_ideal_one():
    scene, problems = parse_scene({}, "p.toml", record_waveforms=False)
    assert problems == []
    assert scene == Scene(fidelity="deformation", signal="features", noise=True, placement_error_mm=0.0)
    assert scene.relaxation_time_s == 30.0 and scene.mains_frequency_hz == 50.0  # the ideal preset's


def test_a_scene_built_in_python_takes_the_presets_knobs_and_refuses_what_the_file_refuses():
    assert dataclasses.asdict(Scene(preset="paper-like")) == dataclasses.asdict(Scene()) | PAPER_LIKE | {
        "preset": "paper-like",
        "deformation": "fe-kernel",  # `auto` resolves to the preset's pinch
    }
    assert Scene(preset="paper-like", adc_skew_us=1.5).adc_skew_us == 1.5
    with pytest.raises(ConfigError) as err:
        Scene(hysteresis_fraction=1.0, noise="yes")  # type: ignore[arg-type]
    _, problems = parse_scene({"hysteresis_fraction": 1.0, "noise": "yes"}, "p.toml", record_waveforms=False)
    assert [(p.field, p.message, p.fix) for p in err.value.problems] == [(p.field, p.message, p.fix) for p in problems]
    with pytest.raises(ConfigError, match="a dent that relaxes in 0 s is no dent"):
        Scene(hysteresis_fraction=0.1, relaxation_time_s=0.0)


def test_the_protocol_schema_reads_the_scene_and_parse_scene_takes_its_table():
    raw = {"preset": "paper-like", "adc_skew_us": 1.5, "temperature_drift_k_per_h": -2.0, "signal": "waveforms"}
    tables, problems = parse_tables(ProtocolFile, {"scene": raw}, "p.toml")
    assert tables["scene"] == Scene(
        signal="waveforms", preset="paper-like", adc_skew_us=1.5, temperature_drift_k_per_h=-2.0
    )
    from_table, none = parse_scene(tables["scene"], "p.toml", record_waveforms=True)
    from_raw, none_either = parse_scene(raw, "p.toml", record_waveforms=True)
    assert none == none_either == [] and from_table == from_raw
    assert from_raw.adc_skew_us == 1.5 and from_raw.temperature_drift_k_per_h == -2.0
    assert from_raw.depth_jitter_mm == PAPER_LIKE["depth_jitter_mm"] == 0.2
    assert not any(p.field and p.field.startswith("scene") for p in problems)


def test_scene_mistakes_name_the_field_and_the_fix():
    raw = {"placment_error_mm": 1.0, "noise": "yes", "hysteresis_fraction": 1.0}
    _, problems = parse_scene(raw, "p.toml", record_waveforms=False)
    shown = [(p.file, p.field, p.message, p.fix) for p in problems]
    assert shown == [
        ("p.toml", "scene.placment_error_mm", "unknown key 'placment_error_mm'", "did you mean 'placement_error_mm'?"),
        ("p.toml", "scene.noise", "'noise' must be true or false, got 'yes'", "set noise = true or false"),
        (
            "p.toml",
            "scene.hysteresis_fraction",
            "'hysteresis_fraction' = 1.0 is above 0.99",
            "set hysteresis_fraction to a number (>= 0, <= 0.99)",
        ),
    ]


def test_a_scene_written_as_a_value_is_one_problem():
    _, problems = parse_scene("paper-like", "p.toml", record_waveforms=False)  # type: ignore[arg-type]
    assert [(p.field, p.message) for p in problems] == [("scene", "[scene] must be a table, got 'paper-like'")]

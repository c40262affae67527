"""The protocol's [scene] on the config schema: one declaration of its keys (neatskin.config.files.SceneTable),
the presets' values in neatskin.sim.scene filling the knobs left out, and the schema's error texts."""

import dataclasses

from neatskin.config.files import SCENE_KNOBS, SCENE_PRESETS, ProtocolFile, SceneTable
from neatskin.config.schema import parse_tables
from neatskin.sim.scene import PAPER_LIKE, PRESETS, Scene, parse_scene


def test_the_schema_declares_every_scene_field_and_the_presets_set_every_knob():
    assert {f.name for f in dataclasses.fields(SceneTable)} == {f.name for f in dataclasses.fields(Scene)}
    assert tuple(PRESETS) == SCENE_PRESETS
    assert all(set(values) == set(SCENE_KNOBS) for values in PRESETS.values())
    assert len(SCENE_KNOBS) == 13 and "surface_error_mm" not in SCENE_KNOBS


def test_an_empty_scene_is_the_ideal_one():
    scene, problems = parse_scene({}, "p.toml", record_waveforms=False)
    assert problems == []
    assert scene == Scene("deformation", "features", True, 0.0, relaxation_time_s=30.0, mains_frequency_hz=50.0)


def test_the_protocol_schema_reads_the_scene_and_parse_scene_takes_its_table():
    raw = {"preset": "paper-like", "adc_skew_us": 1.5, "temperature_drift_k_per_h": -2.0, "signal": "waveforms"}
    tables, problems = parse_tables(ProtocolFile, {"scene": raw}, "p.toml")
    assert tables["scene"] == SceneTable(
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

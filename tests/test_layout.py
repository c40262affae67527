"""Layouts as data: loading, validation errors, pairs, faces and symmetry classes."""

import tomllib

import pytest
from conftest import PROTOCOLS

from neatskin.errors import ConfigError
from neatskin.layout import ElectrodePair, layout_from_dict


def paper_dict():
    return tomllib.loads((PROTOCOLS / "skins" / "paper.toml").read_text())


def test_paper_layout_counts(paper_layout):
    assert (paper_layout.n_junctions, paper_layout.n_channels, paper_layout.n_electrodes) == (9, 12, 8)
    assert len(paper_layout.pairs) == 28
    assert paper_layout.pairs[0] == ElectrodePair(1, 2) and paper_layout.pairs[-1] == ElectrodePair(7, 8)


def test_paper_electrode_positions(paper_layout):
    expected = {1: (15, 0), 2: (30, 0), 3: (30, 15), 4: (30, 30), 5: (15, 30), 6: (0, 30), 7: (0, 15), 8: (0, 0)}
    for e in paper_layout.electrodes:
        j = paper_layout.junctions[e.junction]
        assert (j.x_mm, j.y_mm) == expected[e.number]


def test_pouillet_resistance(paper_layout):
    # rho L / A = 0.5 ohm m * 0.015 m / (2e-3 m * 1e-3 m)
    assert paper_layout.channel_resistance_ohm == pytest.approx([3750.0] * 12, rel=1e-12)


def test_four_quadrants_are_the_bounded_faces(paper_layout):
    faces = paper_layout.faces
    assert len(faces) == 4
    centres = sorted(tuple(paper_layout.xy_mm[list(f)].mean(axis=0)) for f in faces)
    assert centres == [(7.5, 7.5), (7.5, 22.5), (22.5, 7.5), (22.5, 22.5)]


def test_symmetry_classes_of_the_square(paper_layout):
    # the square's 8 isometries; paper Fig. 5 shows 5 classes, the sixth is corner-corner (2,4)
    assert len(paper_layout.symmetries) == 8
    reps = paper_layout.pair_class_representatives()
    assert [str(p) for p in reps] == ["(1,2)", "(1,3)", "(1,4)", "(1,5)", "(2,4)", "(2,6)"]
    assert sum(len(c) for c in paper_layout.pair_classes) == 28


def test_asymmetric_layout_has_only_identity():
    data = paper_dict()
    data["channels"][0]["width_mm"] = 3.0  # one wider edge channel: no isometry maps it onto itself but identity
    layout = layout_from_dict(data)
    assert len(layout.symmetries) == 1
    assert len(layout.pair_classes) == 28


@pytest.mark.parametrize(
    "mutate, field, words",
    [
        (lambda d: d["channels"][0].update({"to": "J99"}), "channels[0].to", "unknown junction"),
        (lambda d: d["channels"].append(dict(d["channels"][0])), "channels[12]", "duplicate channel"),
        (lambda d: d["channels"][3].update({"width_mm": 0}), "channels[3].width_mm", "must be positive"),
        (lambda d: d["channels"][3].update({"height_mm": -1.0}), "channels[3].height_mm", "must be positive"),
        (lambda d: d["electrodes"][2].update({"junction": "nowhere"}), "electrodes[2].junction", "missing junction"),
        (lambda d: d["electrodes"][2].update({"number": 1}), "electrodes[2].number", "duplicate electrode"),
        (lambda d: d["skin"].update({"resistivity_ohm_m": -0.5}), "skin.resistivity_ohm_m", "must be positive"),
        (lambda d: d["junctions"].append({"name": "lost", "x_mm": 50.0, "y_mm": 50.0}), "channels", "disconnected"),
    ],
)
def test_each_layout_mistake_is_named(mutate, field, words):
    data = paper_dict()
    mutate(data)
    with pytest.raises(ConfigError) as info:
        layout_from_dict(data, source="skins/bad.toml")
    problems = info.value.problems
    assert len(problems) == 1, problems
    assert problems[0].file == "skins/bad.toml" and problems[0].field == field
    assert words in problems[0].message and problems[0].fix


def test_several_mistakes_are_reported_at_once():
    data = paper_dict()
    data["channels"][0]["to"] = "J99"
    data["electrodes"][0]["junction"] = "nowhere"
    with pytest.raises(ConfigError) as info:
        layout_from_dict(data, source="x.toml")
    assert {p.field for p in info.value.problems} == {"channels[0].to", "electrodes[0].junction"}


def test_layout_built_in_code_is_validated_too(paper_layout):
    from dataclasses import replace

    from neatskin.layout import Electrode

    twins = paper_layout.electrodes[:-1] + (Electrode(9, paper_layout.electrodes[0].junction),)
    with pytest.raises(ConfigError) as info:
        replace(paper_layout, electrodes=twins)
    assert "share junction" in str(info.value)


def test_misspelt_channel_defaults_is_one_problem_with_a_suggestion():
    # before the schema layer this gave 24 lines of "missing width_mm" / "missing height_mm"
    data = paper_dict()
    data["channel_default"] = data.pop("channel_defaults")
    with pytest.raises(ConfigError) as info:
        layout_from_dict(data, source="skins/bad.toml")
    assert [(p.field, p.message, p.fix) for p in info.value.problems] == [
        ("channel_default", "unknown table [channel_default]", "did you mean 'channel_defaults'?")
    ]


def test_missing_channel_dimensions_are_one_problem_per_dimension():
    data = paper_dict()
    del data["channel_defaults"]
    with pytest.raises(ConfigError) as info:
        layout_from_dict(data, source="skins/bad.toml")
    assert [(p.field, p.message) for p in info.value.problems] == [
        ("channel_defaults", "12 channels have no width_mm (channels[0], channels[1], channels[2], ...)"),
        ("channel_defaults", "12 channels have no height_mm (channels[0], channels[1], channels[2], ...)"),
    ]


@pytest.mark.parametrize(
    "mutate, field, fix",
    [
        (lambda d: d["skin"].update(thickness=5.5), "skin.thickness", "did you mean 'thickness_mm'?"),
        (lambda d: d["channels"][2].update(widht_mm=2.0), "channels[2].widht_mm", "did you mean 'width_mm'?"),
        (lambda d: d["electrodes"][0].update(junktion="J10"), "electrodes[0].junktion", "did you mean 'junction'?"),
    ],
)
def test_unknown_keys_at_every_level_suggest_the_close_one(mutate, field, fix):
    data = paper_dict()
    mutate(data)
    with pytest.raises(ConfigError) as info:
        layout_from_dict(data, source="skins/bad.toml")
    assert [(p.field, p.fix) for p in info.value.problems] == [(field, fix)]

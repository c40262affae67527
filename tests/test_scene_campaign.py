"""Variability scenes in a dry campaign: knobs validated with one clear error each, presets and overrides,
an off source leaves the campaign bit for bit unchanged, carried state (drift, dents, jitter) survives resume
bit for bit, and a drift rate is recovered from a fixed position pressed over time."""

import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.errors import ConfigError
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import resume_campaign, run_campaign
from neatskin.sim.scene import PAPER_LIKE, parse_scene

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

FEATURES = (("waveforms = true", "waveforms = false"), ('signal = "waveforms"', 'signal = "features"'))


def make_protocol(tmp_path, *replacements, scene_lines=(), name="scene.toml"):
    root = tmp_path / "protocols"
    if not root.exists():
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    for old, new in (*FEATURES, *replacements):
        assert old in text, old
        text = text.replace(old, new)
    text = text.rstrip("\n") + "\n" + "".join(line + "\n" for line in scene_lines)
    path = root / name
    path.write_text(text)
    return path


def dr(folder):
    df = pd.read_parquet(folder / "presses.parquet").sort_values("press_id")
    return df.filter(like="dR_ohm_").to_numpy(), df.filter(like="R_ohm_").to_numpy()


@pytest.mark.parametrize(
    "key, value, expect",
    [
        ("depth_jitter_mm", -0.1, "below 0"),
        ("mains_pickup_mv", float("nan"), "finite number"),
        ("adc_skew_us", -2.0, "below 0"),
        ("displaced_fluid_fraction", 1.5, "above 1"),
    ],
)
def test_a_bad_knob_is_one_error_naming_file_field_and_fix(key, value, expect):
    raw = {"fidelity": "deformation", key: value}
    _, problems = parse_scene(raw, "p.toml", record_waveforms=False)
    assert len(problems) == 1
    assert problems[0].field == f"scene.{key}" and problems[0].file == "p.toml"
    assert expect in problems[0].message and key in problems[0].fix


def test_a_bad_knob_stops_the_protocol_before_anything_moves(tmp_path):
    path = make_protocol(tmp_path, scene_lines=("depth_jitter_mm = -0.2",))
    with pytest.raises(ConfigError) as err:
        load_protocol(path)
    assert "scene.depth_jitter_mm" in str(err.value) and str(path.name) in str(err.value)


def test_preset_sets_knobs_and_explicit_knobs_override():
    scene, problems = parse_scene({"preset": "paper-like"}, "p.toml", record_waveforms=False)
    assert not problems and scene.variability() == PAPER_LIKE
    scene, _ = parse_scene(
        {"preset": "paper-like", "adc_skew_us": 0.0, "placement_error_mm": 0.3}, "p", record_waveforms=False
    )
    assert scene.adc_skew_us == 0.0 and scene.placement_error_mm == 0.3
    assert scene.mains_pickup_mv == PAPER_LIKE["mains_pickup_mv"]
    _, problems = parse_scene({"preset": "real"}, "p.toml", record_waveforms=False)
    assert problems and problems[0].field == "scene.preset" and "paper-like" in problems[0].fix


def test_every_source_off_is_the_ideal_scene_bit_for_bit(tmp_path):
    ideal = make_protocol(tmp_path, ("repeats = 2", "repeats = 1"), name="ideal.toml")
    off = make_protocol(
        tmp_path,
        ("repeats = 2", "repeats = 1"),
        ("placement_error_mm = 0.0\n", ""),
        ('preset = "ideal"', 'preset = "paper-like"'),
        # the pinch is the skin model, not a source of variability: the paper-like preset presses the FE kernel,
        # the ideal one the parametric pinch, so the comparison holds the pinch fixed
        scene_lines=[f"{k} = 0.0" for k in PAPER_LIKE if k != "relaxation_time_s"] + ['deformation = "parametric"'],
        name="off.toml",
    )
    run_campaign(load_protocol(ideal), tmp_path / "ideal", progress=False, report=False)
    run_campaign(load_protocol(off), tmp_path / "off", progress=False, report=False)
    a, b = dr(tmp_path / "ideal"), dr(tmp_path / "off")
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()


def test_carried_state_survives_resume_bit_for_bit(tmp_path):
    """Dents of earlier presses, drift and jitter come from the press ids, not from process memory."""
    lines = [
        "hysteresis_fraction = 0.2",
        "relaxation_time_s = 60.0",
        "temperature_drift_k_per_h = 20.0",
        "depth_jitter_mm = 0.1",
        "fabrication_spread_fraction = 0.1",
        "displaced_fluid_fraction = 1.0",
    ]
    path = make_protocol(tmp_path, scene_lines=lines)
    run_campaign(load_protocol(path), tmp_path / "whole", progress=False, report=False)
    run_campaign(load_protocol(path), tmp_path / "split", progress=False, report=False, limit=5)
    resume_campaign(tmp_path / "split", progress=False, report=False)
    whole, split = dr(tmp_path / "whole"), dr(tmp_path / "split")
    assert whole[0].shape == (12, 28)
    assert whole[0].tobytes() == split[0].tobytes() and whole[1].tobytes() == split[1].tobytes()
    ideal = make_protocol(tmp_path, name="ideal.toml")
    run_campaign(load_protocol(ideal), tmp_path / "ideal", progress=False, report=False)
    assert np.abs(dr(tmp_path / "ideal")[0] - whole[0]).max() > 10.0  # and the sources do act


def test_a_drift_rate_is_recovered_from_a_fixed_position_pressed_over_time(tmp_path):
    """20 K/h at -2 %/K is -0.4 per hour of resistivity: the pressed R of one position falls on that line."""
    path = make_protocol(
        tmp_path,
        ("count = 6", "count = 1"),
        ("repeats = 2", "repeats = 10"),
        ("amplitude_a = 0.0002", "amplitude_a = 0.0005"),  # the excitation these tolerances were measured at
        scene_lines=("temperature_drift_k_per_h = 20.0", "press_interval_s = 90.0"),
    )
    run_campaign(load_protocol(path), tmp_path / "run", progress=False, report=False)
    df = pd.read_parquet(tmp_path / "run" / "presses.parquet").sort_values("press_id")
    hours = df.press_id.to_numpy() * 90.0 / 3600.0
    r = df.filter(like="R_ohm_").drop(columns=df.filter(like="dR_ohm_").columns).to_numpy()
    slope = np.polyfit(hours, r / r[0], 1)[0]  # per pair, relative to the first press
    assert slope.shape == (28,)
    # each pair's fit carries its own measurement noise (0.5 mA excitation); their mean averages it out
    np.testing.assert_allclose(slope, -0.4, rtol=5e-3)
    assert abs(slope.mean() / -0.4 - 1) < 5e-4


def test_depth_jitter_and_placement_draws_have_their_set_spread(tmp_path):
    """Each press's depth offset is its own (seed, press_id) stream's N(0, jitter): the std over 4,000 press ids is
    the knob to 5 % (4.5 standard errors), the mean is 0, and the draws do not depend on which presses came before."""
    from neatskin.rig.dryrig import dry_scene
    from neatskin.rig.plan import build_plan
    from neatskin.sim.dryscene import press_conditions
    from neatskin.skin.model import SkinModel

    protocol = load_protocol(make_protocol(tmp_path, scene_lines=("depth_jitter_mm = 0.2",)))
    conditions = press_conditions(dry_scene(protocol, build_plan(protocol)), SkinModel(protocol.layout))
    offsets = np.array([conditions(k).depth_offset_mm for k in range(4000)])
    assert abs(offsets.std() - 0.2) < 0.01 and abs(offsets.mean()) < 0.01
    assert conditions(1234).depth_offset_mm == offsets[1234]
    assert conditions(7).resistivity_factor is None and conditions(7).extra_factor is None  # drift and dents off

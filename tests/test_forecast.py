"""`neatskin campaign plan`: the simulated-campaign engine against the skin model it draws from, rig hours against
the runner's plan, the hours-for-an-error interpolation, and the command end to end on a small protocol."""

import dataclasses

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.errors import ExitCode
from neatskin.rig.forecast import hours_for_error
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan
from neatskin.rig.simcampaign import CampaignSize, rig_hours, simulate_presses, skin_of, strategy_positions


@pytest.fixture(scope="module")
def paper():
    return load_protocol(PROTOCOLS / "paper.toml")


def test_the_protocols_own_size_takes_the_runners_rig_time(paper):
    size = CampaignSize(paper.press.positions.count, paper.press.press.repeats, paper.press.press.depth_mm)
    assert rig_hours(paper, size) == pytest.approx(build_plan(paper).printer_time_s / 3600, rel=1e-12)
    assert rig_hours(paper, CampaignSize(100, 14, 3.5)) < rig_hours(paper, size)


def test_an_ideal_press_is_the_skin_models_change(paper):
    """No placement, jitter, drift or noise: the features are the skin model's dR at the commanded positions."""
    scene = dataclasses.replace(
        paper.scene,
        placement_error_mm=0.0,
        depth_jitter_mm=0.0,
        temperature_drift_k_per_h=0.0,
        evaporation_fraction_per_h=0.0,
    )
    protocol = dataclasses.replace(paper, scene=scene)
    xy = strategy_positions(protocol, 7, 3)
    got = simulate_presses(protocol, xy, 2, 3.5, 0, np.zeros(28), interval_s=7.78)
    skin = skin_of(protocol)
    expected = skin.pair_resistance_ohm(xy[:, 0], xy[:, 1], np.full(7, 3.5)) - skin.baseline_pair_resistance_ohm
    np.testing.assert_allclose(got.features, np.repeat(expected, 2, axis=0), rtol=1e-12, atol=1e-12)
    assert got.groups.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6]
    np.testing.assert_array_equal(got.landed_mm, got.commanded_mm)


def test_the_placement_error_has_the_scenes_spread(paper):
    xy = strategy_positions(paper, 50, 1)
    got = simulate_presses(paper, xy, 40, 3.5, 0, np.full(28, 0.5))
    offsets = got.landed_mm - got.commanded_mm
    sigma = paper.scene.placement_error_mm  # the preset's fitted value
    assert offsets.std(axis=0) == pytest.approx([sigma, sigma], rel=0.05)  # 2,000 draws: about 1.6 % std error


def test_hours_for_an_error_interpolates_in_log_hours_along_the_envelope():
    frame = pd.DataFrame(
        {
            "design": ["random"] * 4,
            "depth_mm": [3.5] * 4,
            "rig_hours": [1.0, 4.0, 2.0, 8.0],
            "mean_error_mm": [4.0, 2.0, 5.0, 1.5],
        }
    )
    # the envelope: 2 h can do what 1 h does (4 mm); 3 mm is halfway from 4 mm at 2 h to 2 mm at 4 h, in log h
    assert hours_for_error(frame, 3.0) == pytest.approx(np.sqrt(2.0 * 4.0))
    assert hours_for_error(frame, 4.5) == pytest.approx(1.0)
    assert hours_for_error(frame, 1.0) is None


def test_campaign_plan_prints_sizes_with_rig_hours_and_errors(tmp_path, capsys):
    code = main(
        [
            "campaign",
            "plan",
            str(PROTOCOLS / "smoke.toml"),
            "--seeds",
            "2",
            "--model",
            "knn",
            "--jobs",
            "1",
            "--out",
            str(tmp_path),
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    rows = [line for line in out.splitlines() if line.startswith("random ")]
    assert len(rows) >= 4 and all(len(r.split()) >= 8 for r in rows)
    frame = pd.read_csv(tmp_path / "campaign_plan.csv")
    assert (frame["seeds"] == 2).all() and (frame["rig_hours"] > 0).all() and (frame["mean_error_mm"] > 0).all()
    assert (tmp_path / "campaign_plan.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_campaign_plan_refuses_one_seed(tmp_path, capsys):
    # a wrong option value is a ConfigError: the exit-code table's CONFIG (3), not argparse's USAGE (2)
    code = main(["campaign", "plan", str(PROTOCOLS / "smoke.toml"), "--seeds", "1", "--out", str(tmp_path)])
    assert code == ExitCode.CONFIG
    assert "--seeds" in capsys.readouterr().err


@pytest.fixture(scope="module")
def kernel_skin(paper):
    """The paper's skin pressing through the packaged finite-element pinch kernel (fidelity 'deformation')."""
    from neatskin.skin.kernel import packaged_kernel_path, read_kernel
    from neatskin.skin.model import SkinModel

    return SkinModel(paper.layout, probe_radius_mm=2.75, kernel=read_kernel(packaged_kernel_path()))


def test_a_kernel_skins_pinch_scales_from_the_same_skin_to_the_unpressed_one(paper, kernel_skin):
    """The negative control's wrong skin on the FE kernel: scale 1 is the skin itself, 0 the unpressed skin (every
    pair at its baseline), and in between each pair's R lies between them (less pinch, no channel narrower)."""
    from neatskin.rig.simcampaign import scale_pinch

    xy = strategy_positions(paper, 12, 5)
    x, y, depth = xy[:, 0], xy[:, 1], np.full(len(xy), 3.5)
    pressed = kernel_skin.pair_resistance_ohm(x, y, depth)
    base = np.broadcast_to(kernel_skin.baseline_pair_resistance_ohm, pressed.shape)
    # every press changes every pair (the quasi-3D kernel: by 0.48 ohm at least, at a quadrant centre), so the
    # scales below are told apart
    assert np.all(pressed > base + 0.1)
    np.testing.assert_array_equal(scale_pinch(kernel_skin, 1.0).pair_resistance_ohm(x, y, depth), pressed)
    np.testing.assert_allclose(scale_pinch(kernel_skin, 0.0).pair_resistance_ohm(x, y, depth), base, rtol=1e-12)
    half = scale_pinch(kernel_skin, 0.5).pair_resistance_ohm(x, y, depth)
    assert np.all((half > base) & (half < pressed))
    more = scale_pinch(kernel_skin, 1.3).pair_resistance_ohm(x, y, depth)
    assert np.all(more >= pressed * (1 - 1e-12))  # a pair more pinch leaves alone may differ in its last bit
    with pytest.raises(ValueError, match="pinch scale"):
        scale_pinch(kernel_skin, -0.1)


def test_a_scaled_kernel_scales_its_pinch_and_clips_it(kernel_skin):
    kernel = kernel_skin.kernel
    assert kernel is not None
    solved = np.isfinite(kernel.area_ratio)
    pinch = 1.0 - np.clip(kernel.area_ratio[solved], 0.0, 1.0)
    np.testing.assert_allclose(1.0 - kernel.scaled(0.5).area_ratio[solved], 0.5 * pinch, atol=1e-15)
    np.testing.assert_array_equal(np.isfinite(kernel.scaled(0.5).area_ratio), solved)
    shut_sooner = kernel.scaled(4.0).area_ratio[solved]
    assert shut_sooner.min() == 0.0 and shut_sooner.max() <= 1.0
    assert kernel.scaled(0.5).key != kernel.key

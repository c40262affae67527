"""`neatskin campaign plan`: the simulated-campaign engine against the skin model it draws from, rig hours against
the runner's plan, the hours-for-an-error interpolation, and the command end to end on a small protocol."""

import dataclasses

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.errors import ExitCode
from neatskin.rig.forecast import PLOT_DPI, hours_for_error, plan_figure
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import build_plan
from neatskin.rig.simcampaign import CampaignSize, rig_hours, simulate_presses, skin_of, strategy_positions


# this module's, made once per worker (module scope remade it whenever the suite's order came back to it)
@pytest.fixture(scope="session")
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


def test_hours_for_an_error_interpolates_in_log_hours_along_the_frontier():
    frame = pd.DataFrame(
        {
            "design": ["random"] * 4,
            "depth_mm": [3.5] * 4,
            "rig_hours": [1.0, 4.0, 2.0, 8.0],
            "mean_error_mm": [4.0, 2.0, 5.0, 1.5],
        }
    )
    # 2 h for 5 mm is dominated by 1 h for 4 mm and left out: 3 mm is halfway from 4 mm at 1 h to 2 mm at 4 h, in log h
    assert hours_for_error(frame, 3.0) == pytest.approx(np.sqrt(1.0 * 4.0))
    assert hours_for_error(frame, 4.5) == pytest.approx(1.0)
    assert hours_for_error(frame, 1.0) is None


def test_the_plans_title_and_labels_lie_inside_the_figure():
    """The PNG's title, axis labels and size labels are drawn inside the figure at its dpi (the one-line title of
    the paper's plan was cut on the right)."""
    rows = []
    for design, shift in (("random", 1.0), ("adaptive", 0.9)):
        for positions, repeats, hours in ((25, 7, 0.38), (50, 7, 0.76), (100, 28, 6.05), (200, 28, 12.1)):
            rows.append((design, positions, repeats, 3.5, hours, shift * 20 / positions**0.5, 0.2))
    rows.append(("random", 100, 28, 2.5, 5.6, 2.6, 0.1))
    frame = pd.DataFrame(
        rows, columns=["design", "positions", "repeats", "depth_mm", "rig_hours", "mean_error_mm", "std_error_mm"]
    )
    fig = plan_figure(frame, protocol_hours=6.05)
    assert fig.dpi == PLOT_DPI  # measured at the dpi the PNG is written at
    renderer = fig.canvas.get_renderer()
    page = fig.bbox
    ax = fig.axes[0]
    texts = [ax.title, ax.xaxis.label, ax.yaxis.label, *ax.texts]
    assert len(ax.texts) == 4  # one label per random size at the protocol's depth
    for text in texts:
        box = text.get_window_extent(renderer)
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1, text.get_text()


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


def test_campaign_plan_shows_its_progress_on_stderr_and_the_same_results_without_it(tmp_path, capsys):
    """The paper's plan ran minutes with nothing on stderr. Now a bar counts the simulated campaigns on stderr (the
    design x size x seed jobs: 14 for smoke.toml with 2 seeds), -q/--quiet (and the old --no-progress) turns it off,
    and the results stay in the same order: the bar's run on 2 processes (joblib's ordered generator) writes the
    CSV and the table byte for byte as a quiet run on one."""
    argv = ["campaign", "plan", str(PROTOCOLS / "smoke.toml"), "--seeds", "2", "--model", "knn"]
    assert main([*argv, "--jobs", "2", "--out", str(tmp_path / "bar")]) == 0
    shown = capsys.readouterr()
    assert main([*argv, "--jobs", "1", "--out", str(tmp_path / "quiet"), "-q"]) == 0
    quiet = capsys.readouterr()
    assert "plan smoke" in shown.err and "14/14" in shown.err and "campaign/s" in shown.err
    assert quiet.err == ""
    assert shown.out.replace(str(tmp_path / "bar"), "OUT") == quiet.out.replace(str(tmp_path / "quiet"), "OUT")
    assert (tmp_path / "bar" / "campaign_plan.csv").read_bytes() == (
        tmp_path / "quiet" / "campaign_plan.csv"
    ).read_bytes()
    assert main([*argv, "--jobs", "1", "--out", str(tmp_path / "old"), "--no-progress"]) == 0
    assert capsys.readouterr().err == ""


def test_campaign_plan_refuses_one_seed(tmp_path, capsys):
    # a wrong option value is a ConfigError: the exit-code table's CONFIG (3), not argparse's USAGE (2)
    code = main(["campaign", "plan", str(PROTOCOLS / "smoke.toml"), "--seeds", "1", "--out", str(tmp_path)])
    assert code == ExitCode.CONFIG
    assert "--seeds" in capsys.readouterr().err


@pytest.fixture(scope="session")
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

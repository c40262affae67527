"""The recorded sensitivity map (`dataset plot`, paper Fig. 8) counts the presses that cut a pair off (a channel
pinched shut: R = dR = +inf, the row flagged `open_circuit:i-j`). A cut pair is the most sensitive reading there is:
its position is drawn at the top of the colour bar with a red x and the title counts it; before, such presses were
left out as flagged and a position where every press cut a pair vanished from the map. The finite values of the other
positions do not move; presses flagged for anything else are still left out."""

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.cli import main
from neatskin.datasets.manifest import create_manifest, update_manifest
from neatskin.datasets.plots import plot_sensitivity_map, sensitivity_by_position, sensitivity_title
from neatskin.datasets.reader import read_presses
from neatskin.datasets.writer import CampaignWriter, file_sha256
from neatskin.skin.synthetic import synthetic_rows

LAYOUT_PATH = PROTOCOLS / "skins" / "paper.toml"


def _frame(flags, dr_12, dr_13):
    return pd.DataFrame(
        {
            "position_id": [0, 0, 1, 1, 2, 3],
            "x_mm": [1.0, 1.0, 2.0, 2.0, 3.0, 4.0],
            "y_mm": [0.0, 0.0, 5.0, 5.0, 9.0, 1.0],
            "flags": flags,
            "dR_ohm_1_2": dr_12,
            "dR_ohm_1_3": dr_13,
        }
    )


CUT = _frame(
    [[], ["open_circuit:1-2"], [], [], ["open_circuit:1-3", "clipped:1-3"], ["fsr_missed"]],
    [10.0, np.inf, -4.0, -8.0, 999.0, 50.0],
    [5.0, 5.0, -2.0, -2.0, np.inf, 50.0],
)


def test_a_press_that_cut_a_pair_is_at_the_top_and_the_finite_values_do_not_move():
    sens = sensitivity_by_position(CUT)
    # position 2 (its one press cut a pair) is present; 3 (a missed FSR, not a cut) is still left out
    assert sens["position_id"].tolist() == [0, 1, 2]
    assert sens["presses"].tolist() == [2, 2, 1] and sens["cut_presses"].tolist() == [1, 0, 1]
    # 0: 1-2 cut in one repeat -> +inf; 1: max(-6, -2) = -2, scaled by the clean presses' largest |z| (10 at
    # position 0's clean press) -> -0.2 exactly, as without the cut presses; 2: 1-3 cut -> +inf
    assert sens["z"].tolist() == [np.inf, -0.2, np.inf]
    assert sens["best_pair"].tolist() == ["1-2", "1-3", "1-3"]
    uncut = sensitivity_by_position(CUT.iloc[[0, 2, 3]])  # the same presses without the cut ones
    assert uncut.set_index("position_id").loc[1, "z"] == sens.set_index("position_id").loc[1, "z"]
    assert sensitivity_title(CUT, sens).splitlines()[1:] == [
        "3 positions, 5 presses",
        "2 presses cut a pair off (dR = inf): 2 positions at the top, marked x",
        "1 otherwise flagged press left out (1 position wholly)",
    ]


def test_a_pair_clipped_but_still_conducting_or_a_row_flag_is_left_out_as_before():
    """The negative control: only a row whose every flag says a pair was cut counts as cut."""
    df = _frame(
        [[], [], ["clipped:1-2"], ["open_circuit:1-2", "no_pressed_sweep"], [], []],
        [10.0, 10.0, 70.0, np.inf, 4.0, 2.0],
        [1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
    )
    sens = sensitivity_by_position(df)
    assert sens["position_id"].tolist() == [0, 2, 3] and sens["cut_presses"].tolist() == [0, 0, 0]
    assert sens["z"].tolist() == [1.0, 0.4, 0.2] and np.isfinite(sens["z"]).all()


def test_a_cut_in_one_repeat_beside_a_cut_baseline_in_another_is_still_cut():
    """+inf (cut while pressed) and -inf (cut at the baseline, conducting pressed) average to NaN, which a max skips:
    the position would have shown a finite value from its other pair."""
    df = _frame(
        [["open_circuit:1-2"], ["open_circuit:1-2"], [], [], [], []],
        [np.inf, -np.inf, 3.0, 3.0, 6.0, 1.0],
        [2.0, 2.0, 1.0, 1.0, 1.0, 1.0],
    )
    sens = sensitivity_by_position(df)
    assert sens["z"].tolist() == [np.inf, 0.5, 1.0, 1.0 / 6.0]


def _campaign(folder, layout, cut: dict[int, int]):
    """6 positions x 3 repeats from the synthetic skin; the presses in `cut` (press index -> pair index) recorded as
    the rig records a pair cut off: R and dR of the pair +inf, the row flagged open_circuit:i-j."""
    rows = synthetic_rows(layout, 6, 3, seed=4, campaign="cut")
    for k, pair in cut.items():
        p = layout.pairs[pair]
        rows[k]["R_ohm"] = rows[k]["R_ohm"].copy()
        rows[k]["dR_ohm"] = rows[k]["dR_ohm"].copy()
        rows[k]["R_ohm"][pair] = rows[k]["dR_ohm"][pair] = np.inf
        rows[k]["flags"] = [f"open_circuit:{p.i}-{p.j}"]
    ref = {"path": str(LAYOUT_PATH), "sha256": file_sha256(LAYOUT_PATH)}
    create_manifest(folder, fsync=False, campaign="cut", seed=4, layout=ref, counts={"planned": 18, "completed": 18})
    with CampaignWriter(folder, layout.pairs, {"seed": 4, "layout": ref}, fsync=False) as writer:
        for row in rows:
            writer.write_press(row)
        writer.finalize()
    update_manifest(folder, fsync=False, status="complete")
    return folder


def _red_pixels(png) -> int:
    """Pixels of the red x marker (matplotlib's 'red', #ff0000, anti-aliased): viridis holds no such colour."""
    import matplotlib.image

    rgb = matplotlib.image.imread(png)[..., :3]
    return int(((rgb[..., 0] > 0.85) & (rgb[..., 1] < 0.25) & (rgb[..., 2] < 0.25)).sum())


@pytest.fixture(scope="module")
def recorded(paper_layout, tmp_path_factory):
    root = tmp_path_factory.mktemp("cut")
    # presses 0-2 are position 0's three repeats (all cut: the position used to vanish); press 7 one repeat of
    # position 2
    cut = _campaign(root / "cut", paper_layout, {0: 5, 1: 5, 2: 9, 7: 0})
    clean = _campaign(root / "clean", paper_layout, {})
    return cut, clean


def test_the_recorded_map_draws_the_cut_positions_and_keeps_the_others(recorded, tmp_path, capsys):
    cut, clean = recorded
    df = read_presses(cut)
    sens = sensitivity_by_position(df).set_index("position_id")
    ref = sensitivity_by_position(read_presses(clean)).set_index("position_id")
    assert sorted(sens.index) == sorted(ref.index) == list(range(6))  # every position drawn, the all-cut one too
    assert sens.loc[0, "z"] == np.inf and sens.loc[0, "cut_presses"] == 3 and sens.loc[0, "presses"] == 3
    assert sens.loc[2, "z"] == np.inf and sens.loc[2, "cut_presses"] == 1
    others = [1, 3, 4, 5]
    assert (sens.loc[others, "cut_presses"] == 0).all()
    # the same skin, the same seed: the other positions' dR are bit for bit those of the uncut campaign; the values
    # are normalised by the clean presses' largest |z|, so they differ from the uncut map's only by one factor
    dr = [c for c in df.columns if c.startswith("dR_ohm_")]
    uncut = read_presses(clean)
    mine, theirs = df[df["position_id"].isin(others)], uncut[uncut["position_id"].isin(others)]
    assert np.array_equal(mine[dr].to_numpy(), theirs[dr].to_numpy())
    ratio = sens.loc[others, "z"] / ref.loc[others, "z"]
    assert np.allclose(ratio, ratio.iloc[0], rtol=1e-12, atol=0) and ratio.iloc[0] > 0
    assert sensitivity_title(df, sensitivity_by_position(df)).splitlines()[1:] == [
        "6 positions, 18 presses",
        "4 presses cut a pair off (dR = inf): 2 positions at the top, marked x",
    ]

    assert main(["dataset", "plot", str(cut), "-o", str(tmp_path / "cut"), "--kind", "sensitivity"]) == 0
    assert main(["dataset", "plot", str(clean), "-o", str(tmp_path / "clean"), "--kind", "sensitivity"]) == 0
    capsys.readouterr()
    assert _red_pixels(tmp_path / "cut" / "sensitivity_map.png") > 20  # two red x markers
    assert _red_pixels(tmp_path / "clean" / "sensitivity_map.png") == 0  # the control: no cut, no marker


def test_the_python_api_writes_the_same_png(recorded, tmp_path):
    cut, _ = recorded
    png = plot_sensitivity_map(cut, tmp_path / "s.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and _red_pixels(png) > 20

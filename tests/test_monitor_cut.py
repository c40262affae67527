"""The monitor's state of a campaign whose presses cut pairs off (a channel pinched shut: R = dR = +inf in the row):
no RuntimeWarning (R - dR was inf - inf: `neatskin: warning (RuntimeWarning in state)` on every poll of a paper-like
run), and the cut values handled as the monitor handles every non-finite value: None (a gap on the page), each pair's
drift reference its first uncut press, the other values exactly R - dR.

The campaign is a small paper-like dry run (30 positions x 1 press; the FE pinch kernel cuts 7 pairs on 5 presses)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from neatskin.cli import main
from neatskin.datasets.reader import read_presses
from neatskin.monitor.state import CampaignView

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def cut_campaign(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("moncut")
    text = (REPO / "protocols" / "paper.toml").read_text()
    for old, new in [
        ("count = 100", "count = 30"),
        ("repeats = 28", "repeats = 1"),
        ('"skins/', f'"{REPO}/protocols/skins/'),
        ('"wiring/', f'"{REPO}/protocols/wiring/'),
        ('"printers/', f'"{REPO}/protocols/printers/'),
    ]:
        assert old in text, old
        text = text.replace(old, new, 1)
    (tmp / "p.toml").write_text(text)
    out = tmp / "run"
    assert main(["campaign", "run", str(tmp / "p.toml"), "--dry-run", "--out", str(out), "--no-report", "-q"]) == 0
    return out


def test_the_drift_of_a_campaign_with_cut_presses_warns_nothing_and_leaves_gaps(cut_campaign):
    df = read_presses(cut_campaign)
    pairs = [c[len("R_ohm_") :] for c in df.columns if c.startswith("R_ohm_")]
    r = df[[f"R_ohm_{p}" for p in pairs]].to_numpy(float)
    dr = df[[f"dR_ohm_{p}" for p in pairs]].to_numpy(float)
    cut = ~np.isfinite(r)
    assert cut.any(axis=1).sum() >= 2 and (np.isposinf(dr) == cut).all()  # the scene cuts pairs off, R and dR inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the RuntimeWarning the monitor printed is an error here
        snapshot = CampaignView(cut_campaign).snapshot()
        json.dumps(snapshot, allow_nan=False)  # the page's JSON: no NaN or inf
    drift = snapshot["drift"]
    assert drift["press_id"] == df["press_id"].tolist()
    pct = np.array([[np.nan if v is None else v for v in col] for col in drift["baseline_pct"]]).T  # (presses, pairs)
    first_uncut = np.argmax(~cut, axis=0)
    expected_first = np.where(cut, np.nan, r - np.where(cut, 0.0, dr))[first_uncut, np.arange(len(pairs))]
    np.testing.assert_array_equal(np.array(drift["baseline_first_ohm"], float), expected_first)
    # a cut value is a gap; every other one exactly (R - dR) against the pair's first uncut press
    assert np.isnan(pct[cut]).all()
    with np.errstate(invalid="ignore"):
        expected = 100.0 * ((r - dr) / expected_first - 1.0)
    np.testing.assert_array_equal(pct[~cut], expected[~cut])
    assert (pct[first_uncut, np.arange(len(pairs))] == 0.0).all()
    # the last press's measured dR: None where it cut a pair, the value elsewhere
    last = snapshot["last_press"]
    assert last["measured_dr_ohm"] == [None if c else float(v) for c, v in zip(cut[-1], dr[-1])]


def test_a_pair_cut_on_the_first_press_takes_its_reference_from_the_next(cut_campaign):
    df = read_presses(cut_campaign)
    pairs = [(int(c.split("_")[2]), int(c.split("_")[3])) for c in df.columns if c.startswith("R_ohm_")]
    r = df[[c for c in df.columns if c.startswith("R_ohm_")]].to_numpy(float)
    cut_press = int(np.flatnonzero(~np.isfinite(r).all(axis=1))[0])
    seen = df.iloc[cut_press:].reset_index(drop=True)  # the campaign's presses from its first cut press on
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        drift = CampaignView._drift(seen, pairs)
    rest = r[cut_press:]
    for k in np.flatnonzero(~np.isfinite(rest[0])):
        col, next_uncut = drift["baseline_pct"][k], int(np.argmax(np.isfinite(rest[:, k])))
        assert next_uncut > 0 and col[0] is None and col[next_uncut] == 0.0
        assert drift["baseline_first_ohm"][k] == float(
            seen[f"R_ohm_{pairs[k][0]}_{pairs[k][1]}"].iloc[next_uncut]
        ) - float(seen[f"dR_ohm_{pairs[k][0]}_{pairs[k][1]}"].iloc[next_uncut])

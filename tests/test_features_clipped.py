"""press_features treats a CLIPPED estimate as the campaign's row does (acquisition.pressvalues): no value, +inf,
never the estimate's finite, low reading; dR = +inf when the pressed group clipped, -inf when the baseline did, 0
with the flag when both did, and the uncertainty of such a dR is +inf. Checked on a real clamped acquisition (the
simulated DAQ at the protocols' 0.2 mA through the paper board's +-8 V rails) and on hand-built estimates."""

from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.estimates import PairEstimates, PairFlag
from neatskin.acquisition.features import features_from_acquisition, press_features
from neatskin.acquisition.pressvalues import press_values
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.sim.daq import NoiseModel, SimulatedDAQ

WIRING = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"
AMPLITUDE_A = 0.0002
R0 = np.linspace(2_000.0, 6_000.0, 28)
CHANGE = np.where(np.arange(28) % 3 == 0, 0.2, 0.0)
T_ON, T_OFF = 0.8, 2.0  # s
PRESSED_OVER, BASELINE_OVER, BOTH_OVER = 4, 7, 11  # the rail at 0.2 mA: 8 V / 0.2 mA - 210 ohm = 39,790 ohm
UNPRESSED_OHM = {PRESSED_OVER: 30_000.0, BASELINE_OVER: 45_000.0, BOTH_OVER: 50_000.0}
PRESSED_OHM = {PRESSED_OVER: 45_000.0, BASELINE_OVER: 30_000.0, BOTH_OVER: 60_000.0}


def skin(t):
    pressed = (t >= T_ON) & (t < T_OFF)
    r = np.broadcast_to(R0 * (1 + CHANGE * pressed[:, None]), (len(t), 28)).copy()
    for pair in UNPRESSED_OHM:
        r[:, pair] = np.where(pressed, PRESSED_OHM[pair], UNPRESSED_OHM[pair])
    return r


def force(t):
    return 4.0 * np.minimum(np.clip((t - T_ON) / 0.02, 0, 1), np.clip((T_OFF - t) / 0.02, 0, 1))


@pytest.mark.parametrize("method", ["lockin", "rms"])
def test_a_clamped_press_gives_no_finite_wrong_delta_r(paper_layout, method):
    wiring = load_wiring(WIRING, paper_layout)
    e = wiring.electrical
    config = DaqConfig(
        amplitude_a=AMPLITUDE_A,
        rail_positive_v=e.supply_positive_v,
        rail_negative_v=e.supply_negative_v,
        mux_series_ohm=2 * e.r_on_ohm + e.r_on_mismatch_ohm,
    )
    sweep = build_sweep(wiring)
    acq = SimulatedDAQ(config, skin, force, noise=NoiseModel.none()).acquire(sweep, 8, rng=np.random.default_rng(0))
    feats, det, est = features_from_acquisition(acq, sweep, method, margin_s=0.01)
    assert det.ok and det.n_presses == 1
    # the estimates themselves keep the finite, low readings (for a curator) and flag them
    pressed_sweeps = (est.windows[:, PRESSED_OVER, 0] >= feats.pressed_samples[PRESSED_OVER, 0]) & (
        est.windows[:, PRESSED_OVER, 1] <= feats.pressed_samples[PRESSED_OVER, 1]
    )
    assert np.isfinite(est.resistance_ohm[pressed_sweeps, PRESSED_OVER]).all()
    assert (est.resistance_ohm[pressed_sweeps, PRESSED_OVER] < PRESSED_OHM[PRESSED_OVER]).all()
    assert (est.flags[pressed_sweeps, PRESSED_OVER] & PairFlag.CLIPPED).all()
    # pressed past the rail: R and dR +inf, the baseline exact
    assert feats.resistance_ohm[PRESSED_OVER] == np.inf and feats.delta_r_ohm[PRESSED_OVER] == np.inf
    assert feats.baseline_ohm[PRESSED_OVER] == pytest.approx(UNPRESSED_OHM[PRESSED_OVER], rel=1e-9)
    # unpressed past the rail, pressed back inside: the baseline +inf, dR -inf, the pressed R exact
    assert feats.baseline_ohm[BASELINE_OVER] == np.inf and feats.delta_r_ohm[BASELINE_OVER] == -np.inf
    assert feats.resistance_ohm[BASELINE_OVER] == pytest.approx(PRESSED_OHM[BASELINE_OVER], rel=1e-9)
    # past it throughout: both +inf, dR 0 with the flag (as two open values)
    assert feats.resistance_ohm[BOTH_OVER] == np.inf == feats.baseline_ohm[BOTH_OVER]
    assert feats.delta_r_ohm[BOTH_OVER] == 0.0
    over = [PRESSED_OVER, BASELINE_OVER, BOTH_OVER]
    assert (feats.flags[over] == PairFlag.CLIPPED).all()
    assert np.isinf(feats.uncertainty_ohm[over]).all()
    # every other pair exactly as without the rails
    ok = np.setdiff1d(np.arange(28), over)
    assert (feats.flags[ok] == 0).all() and np.isfinite(feats.uncertainty_ohm[ok]).all()
    np.testing.assert_allclose(feats.delta_r_ohm[ok], (R0 * CHANGE)[ok], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(feats.baseline_ohm[ok], R0[ok], rtol=1e-9)
    assert not np.isnan(feats.delta_r_ohm).any() and not np.isnan(feats.uncertainty_ohm).any()
    # the campaign's row on the same estimates (its baseline the sweeps before the press, pressed the same
    # sweeps): the same pairs are no value, in the same direction
    marks = {
        "contact": int(det.onset[0] + acq.sample_index[0]) - 100,
        "hold_start": int(feats.pressed_samples[:, 0].min()),
        "hold_end": int(feats.pressed_samples[:, 1].max()),
    }
    labels = [f"{p.i}-{p.j}" for p in paper_layout.pairs]
    row = press_values(est, marks, labels)
    np.testing.assert_array_equal(np.isinf(row.resistance_ohm), np.isinf(feats.resistance_ohm))
    np.testing.assert_array_equal(np.isinf(row.baseline_ohm), np.isinf(feats.baseline_ohm))
    np.testing.assert_array_equal(row.delta_r_ohm[over], feats.delta_r_ohm[over])
    assert {f"clipped:{labels[k]}" for k in over} == {f for f in row.flags if f.startswith("clipped:")}


def _estimates(r, u, flags) -> PairEstimates:
    """4 sweeps x 3 pairs, sweep k live on [100 k, 100 k + 50) for every pair."""
    r, u, flags = (np.asarray(a, dtype=float) for a in (r, u, flags))
    windows = np.stack(np.broadcast_arrays((np.arange(4) * 100)[:, None], (np.arange(4) * 100 + 50)[:, None]), -1)
    windows = np.broadcast_to(windows, (4, 3, 2)).astype(np.int64)
    return PairEstimates(r, u, flags.astype(np.uint8), windows)


C = int(PairFlag.CLIPPED)


def test_hand_built_estimates_give_the_exact_features():
    # sweeps 0, 1 baseline, 2, 3 pressed (press [200, 400)); pair 0 clean, pair 1 clipped in one pressed sweep,
    # pair 2 clipped in one baseline sweep
    r = [[1000, 2000, 3000], [1002, 2002, 3004], [1100, 2500, 2900], [1104, 2504, 2901]]
    u = [[3, 4, 6], [4, 3, 8], [6, 5, 1], [8, 12, 1]]
    flags = [[0, 0, C], [0, 0, 0], [0, C, 0], [0, 0, 0]]
    feats = press_features(_estimates(r, u, flags), 200, 400)
    np.testing.assert_array_equal(feats.n_pressed, [2, 2, 2])
    np.testing.assert_array_equal(feats.n_baseline, [2, 2, 2])
    np.testing.assert_array_equal(feats.baseline_ohm, [1001.0, 2001.0, np.inf])
    np.testing.assert_array_equal(feats.resistance_ohm, [1102.0, np.inf, 2900.5])
    np.testing.assert_array_equal(feats.delta_r_ohm, [101.0, np.inf, -np.inf])
    # pair 0: sqrt(3^2 + 4^2) / 2 and sqrt(6^2 + 8^2) / 2 -> sqrt(2.5^2 + 5^2)
    np.testing.assert_allclose(feats.uncertainty_ohm, [np.sqrt(2.5**2 + 5.0**2), np.inf, np.inf], rtol=1e-15)
    np.testing.assert_array_equal(feats.flags, [0, C, C])


def test_a_clipped_baseline_after_the_press_and_both_groups_clipped():
    # the press covers sweeps 0 and 1: the baseline comes from sweeps 2 and 3 (none before)
    r = [[5000, 7000, 40000], [5002, 7002, 40000], [4000, 6000, 41000], [4002, 6001, 41000]]
    u = np.ones((4, 3))
    flags = [[0, C, C], [0, 0, C], [0, C, C], [0, 0, C]]
    feats = press_features(_estimates(r, u, flags), 0, 200)
    np.testing.assert_array_equal(feats.baseline_ohm, [4001.0, np.inf, np.inf])
    np.testing.assert_array_equal(feats.resistance_ohm, [5001.0, np.inf, np.inf])
    np.testing.assert_array_equal(feats.delta_r_ohm, [1000.0, 0.0, 0.0])
    np.testing.assert_allclose(feats.uncertainty_ohm, [1.0, np.inf, np.inf])
    np.testing.assert_array_equal(feats.flags, [0, C, C])


def test_an_open_pressed_group_beside_a_clipped_one_keeps_both_flags():
    o = int(PairFlag.OPEN_CIRCUIT)
    r = [[1000, 1000, 1000], [1000, 1000, 1000], [np.inf, 900, 1200], [1100, 900, 1200]]
    u = [[1, 1, 1], [1, 1, 1], [np.inf, 1, 1], [1, 1, 1]]
    flags = [[0, 0, 0], [0, 0, 0], [o | C, C, 0], [0, 0, 0]]
    feats = press_features(_estimates(r, u, flags), 200, 400)
    np.testing.assert_array_equal(feats.delta_r_ohm, [np.inf, np.inf, 200.0])
    np.testing.assert_array_equal(feats.flags, [o | C, C, 0])
    np.testing.assert_allclose(feats.uncertainty_ohm, [np.inf, np.inf, 1.0])

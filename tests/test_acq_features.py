"""Per-press features: dR per pair from simulated presses, with the windows they came from."""

from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.estimates import PairFlag
from neatskin.acquisition.features import features_from_acquisition, press_features
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.sim.daq import NoiseModel, SimulatedDAQ

# the paper's 2 mA on a board with +-20 V rails (the DAQ's default is 0.2 mA through the MAX4052 at +-8 V): these
# tests pin the estimator up to 8 kohm, not the mux rails (tests/test_acq_rails.py and test_features_clipped.py do)
BENCH = {"amplitude_a": 0.002, "rail_positive_v": 20.0, "rail_negative_v": -20.0}

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"
R0 = np.linspace(2_000.0, 6_000.0, 28)
CHANGE = np.where(np.arange(28) % 3 == 0, 0.2, 0.0)  # a third of the pairs rise by 20 % under the press
T_ON, T_OFF = 0.8, 2.0  # s


def skin(t):
    pressed = ((t >= T_ON) & (t < T_OFF))[:, None]
    return R0 * (1 + CHANGE * pressed)


def force(t):
    up = np.clip((t - T_ON) / 0.02, 0, 1)
    down = np.clip((T_OFF - t) / 0.02, 0, 1)
    return 4.0 * np.minimum(up, down)


@pytest.fixture(scope="module")
def sweep(paper_layout):
    return build_sweep(load_wiring(PAPER, paper_layout))


def test_ideal_press_gives_exact_delta_r(sweep):
    daq = SimulatedDAQ(DaqConfig(**BENCH), skin, force, noise=NoiseModel.none())
    acq = daq.acquire(sweep, 8, rng=np.random.default_rng(0))  # 2.73 s
    feats, det, est = features_from_acquisition(acq, sweep, "lockin", margin_s=0.01)
    assert det.ok and det.n_presses == 1
    assert det.onset[0] / 1e4 == pytest.approx(T_ON + 0.02 * 0.5 / 4, abs=1e-3)
    np.testing.assert_allclose(feats.delta_r_ohm, R0 * CHANGE, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(feats.baseline_ohm, R0, rtol=1e-9)
    assert np.all(feats.flags == 0)
    # baseline: sweeps 0 and 1 end at 0.683 s < 0.8 s, plus the pairs of sweep 2 live before 0.8 - 0.01 s
    sweep_s = sweep.n_samples / 1e4
    live_start_s = sweep.live_windows[:, 0] / 1e4
    live_stop_s = sweep.live_windows[:, 1] / 1e4
    expect_base = 2 + ((2 * sweep_s + live_stop_s) <= T_ON - 0.01)
    np.testing.assert_array_equal(feats.n_baseline, expect_base)
    starts = np.arange(8)[:, None] * sweep_s + live_start_s
    stops = np.arange(8)[:, None] * sweep_s + live_stop_s
    onset_s = det.onset[0] / 1e4
    expect_pressed = ((starts >= onset_s + 0.01 - 1e-12) & (stops <= det.offset[0] / 1e4 - 0.01 + 1e-12)).sum(axis=0)
    np.testing.assert_array_equal(feats.n_pressed, expect_pressed)
    assert np.all(feats.pressed_samples[:, 0] >= det.onset[0]) and np.all(feats.pressed_samples[:, 1] <= det.offset[0])
    assert np.all(feats.baseline_samples[:, 1] <= det.onset[0])


def test_noisy_press_within_uncertainty(sweep):
    daq = SimulatedDAQ(DaqConfig(**BENCH), skin, force, noise=NoiseModel(voltage_noise_v=0.05, current_noise_a=5e-6))
    acq = daq.acquire(sweep, 8, rng=np.random.default_rng(5))
    feats, det, _ = features_from_acquisition(acq, sweep, "rms", margin_s=0.01)
    z = (feats.delta_r_ohm - R0 * CHANGE) / feats.uncertainty_ohm
    assert det.ok and np.all(np.abs(z) < 5)
    assert np.all(np.abs(feats.delta_r_ohm - R0 * CHANGE) < 0.003 * R0)


def test_missed_press_leaves_every_pair_unpressed(sweep):
    daq = SimulatedDAQ(DaqConfig(**BENCH), skin, None, noise=NoiseModel.none())
    feats, det, _ = features_from_acquisition(daq.acquire(sweep, 3, rng=np.random.default_rng(0)), sweep)
    assert det.flags == ("missed",)
    assert np.all(feats.flags & PairFlag.NO_PRESSED) and np.all(feats.delta_r_ohm == 0)
    assert np.all(np.isinf(feats.uncertainty_ohm)) and np.all(feats.n_pressed == 0)


def test_open_pair_under_press_is_inf_not_nan(sweep):
    def cut(t):
        r = skin(t).copy()
        r[(t >= T_ON) & (t < T_OFF), 5] = np.inf
        return r

    daq = SimulatedDAQ(DaqConfig(**BENCH), cut, force, noise=NoiseModel.none())
    feats, det, est = features_from_acquisition(
        daq.acquire(sweep, 8, rng=np.random.default_rng(0)), sweep, margin_s=0.01
    )
    assert feats.delta_r_ohm[5] == np.inf and feats.resistance_ohm[5] == np.inf
    assert feats.flags[5] & PairFlag.OPEN_CIRCUIT
    assert not np.isnan(feats.delta_r_ohm).any() and not np.isnan(feats.uncertainty_ohm).any()
    ok = np.arange(28) != 5
    np.testing.assert_allclose(feats.delta_r_ohm[ok], (R0 * CHANGE)[ok], rtol=1e-9, atol=1e-6)


def test_press_features_uses_baseline_after_when_none_before(sweep):
    daq = SimulatedDAQ(DaqConfig(**BENCH), skin, force, noise=NoiseModel.none())
    est = daq.estimate_sweep(sweep, np.random.default_rng(0), n_sweeps=4)
    # a press covering the whole first two sweeps: the baseline comes from sweeps 2 and 3
    feats = press_features(est, 0, 2 * sweep.n_samples)
    assert np.all(feats.n_pressed == 2) and np.all(feats.n_baseline == 2)
    assert np.all(feats.baseline_samples[:, 0] >= 2 * sweep.n_samples)


def test_fsr_spikes_and_noise_in_the_simulated_daq_do_not_break_the_label(sweep):
    noise = NoiseModel(fsr_noise_v=0.02, fsr_spike_rate_hz=20.0, fsr_spike_v=3.0)
    daq = SimulatedDAQ(DaqConfig(**BENCH), skin, force, noise=noise)
    acq = daq.acquire(sweep, 8, rng=np.random.default_rng(2))
    fsr = acq.fsr_v
    jumps = np.abs(np.diff(fsr)) > 1.0
    assert jumps.sum() >= 40  # ~55 spikes, each two edges, were injected
    feats, det, _ = features_from_acquisition(acq, sweep, "lockin", margin_s=0.01)
    assert det.ok and det.n_presses == 1
    assert det.onset[0] / 1e4 == pytest.approx(T_ON + 0.02 * 0.5 / 4, abs=2e-3)
    np.testing.assert_allclose(det.peak_force_n, 4.0, rtol=0.05)
    assert np.all(np.abs(feats.delta_r_ohm - R0 * CHANGE) < 0.002 * R0)

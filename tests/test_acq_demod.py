"""Demodulation on simulated waveforms: RMS and lock-in recover known resistances, flags, and the features-only path."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.demod import demodulate, window_counts
from neatskin.acquisition.estimates import PairFlag, flag_names
from neatskin.acquisition.sequence import SweepTiming, build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.sim.daq import NoiseModel, SimulatedDAQ

# the paper's 2 mA on a board with +-20 V rails (the DAQ's default is 0.5 mA through the MAX4052 at +-8 V): these
# tests pin the estimator up to 8 kohm, not the mux rails (tests/test_acq_rails.py does)
BENCH = {"amplitude_a": 0.002, "rail_positive_v": 20.0, "rail_negative_v": -20.0}

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"
R_TRUE = np.linspace(2_000.0, 8_000.0, 28)  # ohm, inside the default +-10 V range at 2 mA
NOISY = NoiseModel(voltage_noise_v=0.3, current_noise_a=3e-5)  # ~2 % of the signal per sample


def constant(r):
    r = np.asarray(r, dtype=float)
    return lambda t: np.broadcast_to(r, (len(t), r.shape[0]))


@pytest.fixture(scope="module")
def sweep(paper_layout):
    return build_sweep(load_wiring(PAPER, paper_layout))


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_ideal_instrument_is_exact(sweep, method):
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=NoiseModel.none())
    est = demodulate(daq.acquire(sweep, 2, rng=np.random.default_rng(0)), sweep, method)
    assert est.resistance_ohm.shape == (2, 28)
    np.testing.assert_allclose(est.resistance_ohm, np.broadcast_to(R_TRUE, (2, 28)), rtol=1e-9)
    assert np.all(est.flags == 0)
    assert est.windows[1, 0].tolist() == [sweep.n_samples + 22, sweep.n_samples + 122]


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_default_rig_noise_within_0_05_percent(sweep, method):
    # default noise: 2 mV and 0.1 uA white, 16-bit quantisation, switching transients (discarded with the settle)
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE))
    est = demodulate(daq.acquire(sweep, 3, rng=np.random.default_rng(1)), sweep, method)
    assert np.max(np.abs(est.resistance_ohm / R_TRUE - 1)) < 5e-4
    assert np.all(est.flags == 0)


def test_settle_samples_discard_the_switching_transient(paper_layout):
    wiring = load_wiring(PAPER, paper_layout)
    noise = NoiseModel(0, 0, 0, quantise=False, clip=False, transient_v=0.5, transient_tau_samples=3.0)
    errors = {}
    for settle in (0, 30):
        sweep = build_sweep(wiring, SweepTiming(settle_samples=settle))
        daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=noise)
        est = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0)), sweep, "rms")
        errors[settle] = np.max(np.abs(est.resistance_ohm / R_TRUE - 1))
    assert errors[0] > 2e-4  # the transient biases an undiscarded window
    assert errors[30] < 1e-6  # 0.5 V * exp(-10) left


def _relative_errors(sweep, noise, n_sweeps, seed):
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=noise)
    acq = daq.acquire(sweep, n_sweeps, rng=np.random.default_rng(seed))
    return {m: demodulate(acq, sweep, m).resistance_ohm / R_TRUE - 1 for m in ("rms", "lockin")}


def test_lockin_tighter_than_rms_at_a_fixed_seed(sweep):
    err = _relative_errors(sweep, NOISY, 10, seed=7)
    rmse = {m: float(np.sqrt(np.mean(e**2))) for m, e in err.items()}
    assert rmse["lockin"] < 0.95 * rmse["rms"]
    assert rmse["lockin"] < 0.007  # 2/N (sigma_v^2/V0^2 + sigma_i^2/I0^2) ~ 0.0055 on average


def test_lockin_tighter_than_rms_over_many_seeds(sweep):
    # same window (the 100-sample live window), same noise, 40 seeds x 5 sweeps x 28 pairs
    wins = 0
    all_err = {"rms": [], "lockin": []}
    for seed in range(40):
        err = _relative_errors(sweep, NOISY, 5, seed)
        rmse = {m: np.sqrt(np.mean(e**2)) for m, e in err.items()}
        wins += rmse["lockin"] < rmse["rms"]
        for m in err:
            all_err[m].append(err[m])
    # white noise alone: the two share their first-order variance, so the margin is small (lock-in wins
    # ~35 of 40 seeds at 140 estimates each); 32 of 40 has probability 1e-4 if they were equal
    assert wins >= 32
    rms, lockin = (np.concatenate(all_err[m]) for m in ("rms", "lockin"))
    # RMS rectifies noise: biased upward by sigma_v^2/V0^2 - sigma_i^2/I0^2 (~1.2e-3 here); lock-in is unbiased
    assert abs(lockin.mean()) < 2e-4
    assert 8e-4 < rms.mean() < 1.6e-3
    assert np.sqrt(np.mean(lockin**2)) < 0.97 * np.sqrt(np.mean(rms**2))


def test_dc_offset_flagged_and_only_biases_rms(sweep):
    err = _relative_errors(sweep, NoiseModel(voltage_offset_v=0.3), 2, seed=3)
    assert np.max(np.abs(err["lockin"])) < 3e-4
    # rms^2 picks up offset^2: R reads high by ~offset^2 / V0^2 (0.35 % at 2 kohm, 0.035 % at 8 kohm)
    expected = np.sqrt(1 + 0.3**2 / ((R_TRUE * 0.002) ** 2 / 2)) - 1
    np.testing.assert_allclose(err["rms"].mean(axis=0), expected, rtol=0.1)
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=NoiseModel(voltage_offset_v=0.3))
    est = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0)), sweep)
    # 0.3 V is above 5 % of the AC RMS (V0 / sqrt 2) for V0 < 8.5 V, i.e. R < 4.24 kohm
    flagged = R_TRUE * 0.002 / np.sqrt(2) * 0.05 < 0.3
    assert 5 < flagged.sum() < 23
    assert np.all(est.flags[0, flagged] == PairFlag.DC_OFFSET) and np.all(est.flags[0, ~flagged] == 0)
    assert flag_names(est.flags[0, 0]) == ("dc_offset",)


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_clipping_and_open_circuit_flagged_others_exact(sweep, method):
    r = R_TRUE.copy()
    r[[3, 10]] = np.inf  # cut-off electrode: no current
    r[[5, 20]] = 0.0  # a dead short: zero volts, still a finite reading
    cfg = DaqConfig(voltage_range_v=2.0, **BENCH)  # +-4 V across the pair: 2 mA clips above 2 kohm
    r[r > 2_000] = np.where(np.isinf(r[r > 2_000]), np.inf, 1_500.0)
    r[[7, 8]] = 4_000.0  # these clip
    daq = SimulatedDAQ(cfg, constant(r), noise=NoiseModel(0, 0, 0, quantise=False, clip=True, transient_v=0.0))
    est = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0)), sweep, method)
    flags = est.flags[0]
    assert np.all(flags[[3, 10]] & PairFlag.OPEN_CIRCUIT)
    assert np.all(np.isinf(est.resistance_ohm[0, [3, 10]])) and np.all(np.isinf(est.uncertainty_ohm[0, [3, 10]]))
    assert np.all(flags[[7, 8]] == PairFlag.CLIPPED)
    assert np.all(est.resistance_ohm[0, [7, 8]] < 4_000.0)  # clipped peaks read low
    ok = np.setdiff1d(np.arange(28), [3, 10, 7, 8])
    assert np.all(flags[ok] == 0)
    np.testing.assert_allclose(est.resistance_ohm[0, ok], r[ok], rtol=1e-9, atol=1e-9)
    assert not np.isnan(est.resistance_ohm).any()


def test_zero_current_everywhere_never_divides_by_zero(sweep):
    daq = SimulatedDAQ(DaqConfig(), constant(np.full(28, np.inf)), noise=NoiseModel())
    with np.errstate(all="raise"):
        for method in ("rms", "lockin"):
            est = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0)), sweep, method)
            assert np.all(est.flags & PairFlag.OPEN_CIRCUIT) and np.all(np.isinf(est.resistance_ohm))


def test_drift_follows_the_live_window_midpoint(sweep):
    noise = NoiseModel(0, 0, 0, quantise=False, clip=False, transient_v=0.0, drift_per_s=0.01)
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=noise)
    est = demodulate(daq.acquire(sweep, 2, rng=np.random.default_rng(0), start_time_s=10.0), sweep, "lockin")
    mid_s = 10.0 + (np.arange(2)[:, None] * sweep.n_samples + sweep.live_windows.mean(axis=1)) / 10_000.0
    np.testing.assert_allclose(est.resistance_ohm, R_TRUE * (1 + 0.01 * mid_s), rtol=1e-9)


def test_window_counts():
    assert window_counts(5, 2).tolist() == [1, 2, 2, 2, 1]
    assert window_counts(100, 10).sum() == 10 * 91


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_features_only_path_matches_waveform_statistics(sweep, method):
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=NOISY)
    n = 300
    wave = demodulate(daq.acquire(sweep, n, rng=np.random.default_rng(11)), sweep, method)
    fallbacks = []
    waveform_path = daq.acquire
    daq.acquire = lambda *a, **k: fallbacks.append(1) or waveform_path(*a, **k)
    fast = daq.estimate_sweep(sweep, np.random.default_rng(12), method=method, n_sweeps=n)
    assert fallbacks == []  # the fast path itself, not a fallback to waveforms
    assert fast.resistance_ohm.shape == wave.resistance_ohm.shape == (n, 28)
    np.testing.assert_array_equal(fast.windows, wave.windows)
    wr, fr = wave.resistance_ohm / R_TRUE - 1, fast.resistance_ohm / R_TRUE - 1
    sd_w, sd_f = wr.std(axis=0), fr.std(axis=0)  # per pair, over sweeps
    # per-pair std within 20 % (300 draws: std of a std ~4 %), pooled within 5 %
    assert np.all(np.abs(sd_f / sd_w - 1) < 0.2)
    assert abs(sd_f.mean() / sd_w.mean() - 1) < 0.05
    # means agree within 4 standard errors of the pooled difference
    se = np.sqrt((sd_w.mean() ** 2 + sd_f.mean() ** 2) / (n * 28))
    assert abs(wr.mean() - fr.mean()) < 4 * se
    # reported uncertainties agree too
    assert abs(fast.uncertainty_ohm.mean() / wave.uncertainty_ohm.mean() - 1) < 0.1
    assert np.all(fast.flags == wave.flags)


def test_features_only_path_falls_back_for_open_and_clipped(sweep):
    r = R_TRUE.copy()
    r[4] = np.inf
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(r))
    fast = daq.estimate_sweep(sweep, np.random.default_rng(0))
    # the galvanostat rails at its 50 V compliance: open, and the voltage channel clips too
    assert fast.flags[0, 4] == PairFlag.OPEN_CIRCUIT | PairFlag.CLIPPED and np.isinf(fast.resistance_ohm[0, 4])
    assert np.all(fast.flags[0, np.arange(28) != 4] == 0)


def test_features_only_path_flags_dc_offset_like_the_waveform_path(sweep):
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE), noise=NoiseModel(voltage_offset_v=0.3))
    wave = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0)), sweep)
    fast = daq.estimate_sweep(sweep, np.random.default_rng(0))
    np.testing.assert_array_equal(fast.flags, wave.flags)
    assert np.count_nonzero(fast.flags) > 5


def test_same_rng_same_samples_and_rng_required(sweep):
    from neatskin.errors import ConfigError

    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE))
    a = daq.acquire(sweep, 2, rng=np.random.default_rng(42), start_time_s=5.0)
    b = daq.acquire(sweep, 2, rng=np.random.default_rng(42), start_time_s=5.0)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.sample_index[0] == 50_000
    with pytest.raises(ConfigError, match="needs an explicit rng"):
        daq.acquire(sweep)


def test_skin_callable_of_the_wrong_shape_refused(sweep):
    from neatskin.errors import ConfigError

    daq = SimulatedDAQ(DaqConfig(**BENCH), lambda t: np.ones((len(t), 27)))
    with pytest.raises(ConfigError, match=r"returned shape \(28, 27\), expected \(28, 28\)"):
        daq.acquire(sweep, rng=np.random.default_rng(0))


def test_per_sample_resistance_follows_a_ramp(sweep):
    # R rising 2 % per second, evaluated at every sample: the lock-in reads the live window's mean,
    # i.e. R at its midpoint (exact for a linear ramp, up to the sin^2 weighting over whole periods)
    def ramp(t):
        return R_TRUE[None, :] * (1 + 0.02 * t[:, None])

    per_sample = SimulatedDAQ(DaqConfig(**BENCH), ramp, noise=NoiseModel.none(), resistance_sampling="per_sample")
    est = demodulate(per_sample.acquire(sweep, rng=np.random.default_rng(0)), sweep, "lockin")
    mid_s = (sweep.live_windows.mean(axis=1) - 0.5) / 10_000.0
    np.testing.assert_allclose(est.resistance_ohm[0], R_TRUE * (1 + 0.02 * mid_s), rtol=3e-6)
    per_pair = SimulatedDAQ(DaqConfig(**BENCH), ramp, noise=NoiseModel.none())
    est2 = demodulate(per_pair.acquire(sweep, rng=np.random.default_rng(0)), sweep, "lockin")
    np.testing.assert_allclose(est2.resistance_ohm, est.resistance_ohm, rtol=1e-5)


def test_estimator_moments_closed_form(sweep):
    from neatskin.sim.daq import effective_noise_var, estimator_moments

    cfg = DaqConfig(**BENCH)
    noise = NoiseModel(voltage_noise_v=0.3, current_noise_a=3e-5, quantise=False)
    r = R_TRUE[None, :]
    mean, std, blocks = estimator_moments(r, sweep, cfg, noise, "lockin")
    assert effective_noise_var(cfg, noise) == (0.3**2, 3e-5**2) and blocks == 10
    np.testing.assert_allclose(mean, r)
    np.testing.assert_allclose(std, r * np.sqrt(2 / 100 * ((0.3 / (r * 0.002)) ** 2 + (3e-5 / 0.002) ** 2)))
    mean_rms, std_rms, blocks_rms = estimator_moments(r, sweep, cfg, noise, "rms", 10)
    # rectification bias sigma_v^2 / V0^2 - sigma_i^2 / A^2 (to first order), and a slightly larger spread
    np.testing.assert_allclose(mean_rms / r - 1, (0.3 / (r * 0.002)) ** 2 - (3e-5 / 0.002) ** 2, rtol=0.05)
    assert np.all(std_rms > std) and np.all(std_rms < 1.1 * std) and blocks_rms == 10


@settings(max_examples=25, deadline=None)
@given(
    r=st.lists(st.floats(0.0, 9_500.0), min_size=28, max_size=28),
    start=st.integers(0, 10**9),
    method=st.sampled_from(["rms", "lockin"]),
)
def test_ideal_instrument_recovers_any_resistance(sweep, r, start, method):
    """Any resistance in range (a dead short included), any start on the sample clock: exact, unflagged."""
    r = np.array(r)
    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(r), noise=NoiseModel.none())
    est = demodulate(daq.acquire(sweep, rng=np.random.default_rng(0), start_time_s=start / 10_000.0), sweep, method)
    np.testing.assert_allclose(est.resistance_ohm[0], r, rtol=1e-9, atol=1e-9)
    assert np.all(est.flags == 0) and est.windows[0, 0, 0] == start + 22


def test_bad_method_and_window_refused(sweep):
    from neatskin.errors import ConfigError

    daq = SimulatedDAQ(DaqConfig(**BENCH), constant(R_TRUE))
    acq = daq.acquire(sweep, rng=np.random.default_rng(0))
    with pytest.raises(ConfigError, match="unknown demodulation 'fft'"):
        demodulate(acq, sweep, "fft")
    with pytest.raises(ConfigError, match="RMS window 101 does not fit the live window of 100 samples"):
        demodulate(acq, sweep, "rms", 101)
    other = build_sweep(load_wiring(PAPER, _layout()), SweepTiming(live_samples=50))
    with pytest.raises(ConfigError, match="demodulate with the sweep it was acquired with"):
        demodulate(acq, other)


def _layout():
    from neatskin.layout import load_layout

    return load_layout(PAPER.parent.parent / "skins" / "paper.toml")

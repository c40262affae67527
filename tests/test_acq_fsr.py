"""FSR: the divider model and press detection on noisy traces with spikes and drift."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.acquisition.fsr import FsrModel, detect_presses

RATE = 10_000.0


def trace(onsets_s, duration_s=8.0, peak_n=3.0, hold_s=0.5, ramp_s=0.1, noise_n=0.05, spikes=40, drift_n=0.3, seed=0):
    """Force: trapezoid presses on a drifting baseline, white noise and single-sample spikes."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * RATE)) / RATE
    force = np.zeros_like(t)
    for t0 in onsets_s:
        up = np.clip((t - t0) / ramp_s, 0, 1)
        down = np.clip((t0 + ramp_s + hold_s + ramp_s - t) / ramp_s, 0, 1)
        force += peak_n * np.minimum(up, down)
    force += drift_n * (0.5 + 0.5 * np.sin(2 * np.pi * t / (2 * duration_s)))  # slow drift
    force += noise_n * rng.standard_normal(t.size)
    where = rng.choice(t.size, spikes, replace=False)
    force[where] += rng.choice([-1, 1], spikes) * rng.uniform(2, 6, spikes)  # spikes bigger than the presses
    return t, force


def test_divider_round_trip_and_knee():
    fsr = FsrModel()
    force = np.array([0.0, 0.1, 1.0, 5.0, 20.0])
    v = fsr.volts(force)
    assert v[0] == 0.0 and v[2] == pytest.approx(2.5)  # knee: k / Rm = 1 N gives Vcc / 2
    np.testing.assert_allclose(fsr.newtons(v), force, rtol=1e-12)
    assert np.all(np.diff(v) > 0)
    assert np.isfinite(fsr.newtons(np.array([5.0, 6.0, -1.0]))).all()


def test_finds_exactly_the_commanded_presses():
    onsets = [1.0, 2.5, 4.0, 6.2]
    t, force = trace(onsets)
    det = detect_presses(force, RATE, expected=4)
    assert det.n_presses == 4 and det.ok and det.flags == ()
    # the 0.5 N threshold is crossed a sixth of the way up a 3 N, 0.1 s ramp
    np.testing.assert_allclose(det.onset / RATE, np.array(onsets) + 0.1 / 6, atol=0.01)
    # 0.25 N off threshold: 1/12 of the ramp before the end of the fall
    np.testing.assert_allclose(det.offset / RATE, np.array(onsets) + 0.7 - 0.1 / 12, atol=0.01)
    np.testing.assert_allclose(det.peak_force_n, 3.0, atol=0.05)
    assert np.all((det.peak_index >= det.onset) & (det.peak_index < det.offset))


def test_fsr_volts_input():
    t, force = trace([1.5, 4.5], noise_n=0.02)
    fsr = FsrModel()
    det = detect_presses(fsr.volts(force), RATE, expected=2, units="v", fsr=fsr)
    assert det.n_presses == 2 and det.ok
    np.testing.assert_allclose(det.onset / RATE, np.array([1.5, 4.5]) + 0.1 / 6, atol=0.01)


def test_missed_press_is_flagged():
    t, force = trace([], duration_s=3.0)
    det = detect_presses(force, RATE, expected=1)
    assert det.n_presses == 0 and det.flags == ("missed",) and not det.ok
    # a press too light to cross the threshold is a miss, not a press
    t, force = trace([1.0], duration_s=3.0, peak_n=0.3)
    assert detect_presses(force, RATE, expected=1).flags == ("missed",)


def test_two_presses_where_one_was_commanded_is_flagged():
    t, force = trace([0.5, 2.0], duration_s=4.0)
    det = detect_presses(force, RATE, expected=1)
    assert det.n_presses == 2 and det.flags == ("multiple",)


def test_bounce_is_debounced_and_hysteresis_holds():
    t, force = trace([1.0], duration_s=3.0, noise_n=0.0, spikes=0, drift_n=0.0)
    # a 20 ms release to 0.1 N in the middle of the hold: one press, not two
    force[(t > 1.35) & (t < 1.37)] = 0.1
    assert detect_presses(force, RATE, expected=1).n_presses == 1
    # a plateau hovering around the on threshold with noise: crossings, but one press
    rng = np.random.default_rng(1)
    plateau = np.where((t > 1.0) & (t < 2.0), 0.5 + 0.1 * rng.standard_normal(t.size), 0.0)
    det = detect_presses(plateau, RATE, expected=1)
    assert det.n_presses == 1


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 4), seed=st.integers(0, 10_000))
def test_property_count_matches_commanded(n, seed):
    onsets = [0.6 + 1.6 * k for k in range(n)]
    t, force = trace(onsets, duration_s=7.5, seed=seed)
    det = detect_presses(force, RATE, expected=max(n, 1))
    assert det.n_presses == n


def test_steep_linear_drift_and_decimated_trace():
    onsets = [1.0, 2.5, 4.0, 6.2]
    t, force = trace(onsets, seed=3)
    force = force + 1.5 * t / 8.0  # 1.5 N of drift, six times the off threshold
    det = detect_presses(force, RATE, expected=4)
    assert det.n_presses == 4 and det.ok
    np.testing.assert_allclose(det.peak_force_n, 3.0, atol=0.05)  # measured above the drifting baseline
    # the campaign's features-only scene keeps the FSR at 1 kHz: same presses, same onsets
    det_1k = detect_presses(force[::10], RATE / 10, expected=4)
    assert det_1k.n_presses == 4
    np.testing.assert_allclose(det_1k.onset / (RATE / 10), np.array(onsets) + 0.1 / 6, atol=0.01)


def test_bad_thresholds_refused():
    from neatskin.errors import ConfigError

    with pytest.raises(ConfigError, match="off_threshold_n < on_threshold_n"):
        detect_presses(np.zeros(100), RATE, on_threshold_n=0.2, off_threshold_n=0.3)
    with pytest.raises(ConfigError, match="units must be 'n' or 'v'"):
        detect_presses(np.zeros(100), RATE, units="lbf")
    empty = detect_presses(np.zeros(0), RATE)
    assert empty.n_presses == 0 and empty.flags == ("missed",)

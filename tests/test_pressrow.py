"""A press's row values: baseline and pressed sweeps chosen by the motion marks, open circuits, flags, FSR labels."""

import numpy as np
import pytest

from neatskin.acquisition.estimates import PairEstimates, PairFlag, flag_names
from neatskin.acquisition.fsr import FsrModel
from neatskin.acquisition.pressvalues import press_values
from neatskin.rig.pressrow import fsr_label

MARKS = {"contact": 300, "hold_start": 500, "hold_end": 800, "lifted": 1000}


def estimates(r, flags=None, sweep_samples=100, pairs=3):
    """Sweeps of `sweep_samples`, each pair's window a tenth of it, one after the other."""
    r = np.asarray(r, dtype=float)
    sweeps = r.shape[0]
    start = np.arange(sweeps)[:, None] * sweep_samples + np.arange(pairs)[None, :] * (sweep_samples // pairs)
    windows = np.stack([start, start + sweep_samples // 10], axis=-1)
    flags = np.zeros(r.shape, np.uint8) if flags is None else np.asarray(flags, np.uint8)
    return PairEstimates(r, np.zeros_like(r), flags, windows)


def reference_press_values(est, marks, labels):
    """The row values as first written (commit 80806b2): one mask at a time, flags named pair by pair; since the
    mux rails were modelled a CLIPPED sweep is no value, as an open one (+inf): the reading it gives is wrong."""

    def mean_over(use):
        count = use.sum(axis=0)
        total = np.where(use, est.resistance_ohm, 0.0).sum(axis=0)
        clipped = (est.flags & PairFlag.CLIPPED) != 0
        inf = (use & (np.isinf(est.resistance_ohm) | clipped)).any(axis=0)
        mean = np.where(inf, np.inf, total / np.maximum(count, 1))
        flags = np.bitwise_or.reduce(np.where(use, est.flags, 0).astype(np.uint8), axis=0)
        return np.where(count > 0, mean, np.nan), flags

    start, stop = est.windows[..., 0], est.windows[..., 1]
    b_use = stop <= marks["contact"]
    p_use = (start >= marks["hold_start"]) & (stop <= marks["hold_end"])
    with np.errstate(invalid="ignore"):
        r_b, f_b = mean_over(b_use)
        r_p, f_p = mean_over(p_use)
        delta = np.where(np.isinf(r_b) & np.isinf(r_p), 0.0, r_p - r_b)
    flags = ["no_baseline_sweep"] * (not b_use.any()) + ["no_pressed_sweep"] * (not p_use.any())
    flags += [f"{name}:{label}" for label, bits in zip(labels, f_b | f_p) for name in flag_names(int(bits))]
    return r_p, r_b, delta, tuple(flags), int(b_use.any(axis=1).sum()), int(p_use.all(axis=1).sum())


def test_baseline_before_contact_pressed_inside_the_hold():
    # sweeps 0-2 end before contact (300), 5-7 lie inside the hold (500..800), 3, 4, 8, 9 neither
    r = np.array([[100.0, 200.0, 300.0]] * 10)
    r[5:8] += [[10.0, 20.0, 30.0], [12.0, 22.0, 32.0], [14.0, 24.0, 34.0]]
    r[3:5] = 1e9  # sweeps while descending do not count
    v = press_values(estimates(r), MARKS, ["1-2", "1-3", "1-4"])
    np.testing.assert_array_equal(v.baseline_ohm, [100.0, 200.0, 300.0])
    np.testing.assert_array_equal(v.resistance_ohm, [112.0, 222.0, 332.0])
    np.testing.assert_array_equal(v.delta_r_ohm, [12.0, 22.0, 32.0])
    assert (v.n_baseline, v.n_pressed, v.flags) == (3, 3, ())


def test_open_circuits_missing_sweeps_and_flags_are_named():
    r = np.full((10, 3), 500.0)
    flags = np.zeros((10, 3), np.uint8)
    r[1, 0] = np.inf  # pair 0 open in one baseline sweep ...
    r[6, 0] = np.inf  # ... and in one pressed sweep: both open, dR 0
    r[6, 2] = np.inf  # pair 2 open only while pressed: dR inf
    flags[1, 0] = PairFlag.OPEN_CIRCUIT
    flags[6, 0] = PairFlag.OPEN_CIRCUIT | PairFlag.CLIPPED
    flags[6, 2] = PairFlag.OPEN_CIRCUIT
    flags[9, 1] = PairFlag.CLIPPED  # after the hold: not used, not named
    v = press_values(estimates(r, flags), MARKS, ["a", "b", "c"])
    np.testing.assert_array_equal(v.baseline_ohm, [np.inf, 500.0, 500.0])
    np.testing.assert_array_equal(v.resistance_ohm, [np.inf, 500.0, np.inf])
    np.testing.assert_array_equal(v.delta_r_ohm, [0.0, 0.0, np.inf])
    assert v.flags == ("open_circuit:a", "clipped:a", "open_circuit:c")
    # a pressed sweep clipped (the ADC's range or a mux rail) with a finite, low value: the pair is no value
    flags[7, 1] = PairFlag.CLIPPED
    r[7, 1] = 300.0
    v = press_values(estimates(r, flags), MARKS, ["a", "b", "c"])
    np.testing.assert_array_equal(v.resistance_ohm, [np.inf, np.inf, np.inf])
    np.testing.assert_array_equal(v.delta_r_ohm, [0.0, np.inf, np.inf])
    assert v.flags == ("open_circuit:a", "clipped:a", "clipped:b", "open_circuit:c")
    # no sweep inside the hold: NaN, flagged
    late = dict(MARKS, hold_start=2000, hold_end=2500)
    v = press_values(estimates(r[:3]), late, ["a", "b", "c"])
    assert np.isnan(v.resistance_ohm).all() and np.isnan(v.delta_r_ohm).all()
    assert v.flags == ("no_pressed_sweep",) and (v.n_baseline, v.n_pressed) == (3, 0)


@pytest.mark.parametrize("seed", range(6))
def test_same_values_as_the_first_implementation(seed):
    rng = np.random.default_rng(seed)
    r = rng.uniform(1e3, 1e4, (25, 28))
    r[rng.random(r.shape) < 0.05] = np.inf
    flags = np.where(rng.random(r.shape) < 0.1, rng.integers(0, 64, r.shape), 0)
    est = estimates(r, flags, sweep_samples=3416, pairs=28)
    labels = [f"p{k}" for k in range(28)]
    marks = {
        "contact": int(rng.integers(0, 40_000)),
        "hold_start": 38_200,
        "hold_end": int(rng.integers(38_200, 90_000)),
    }
    v = press_values(est, marks, labels)
    r_p, r_b, delta, names, n_b, n_p = reference_press_values(est, marks, labels)
    for got, want in ((v.resistance_ohm, r_p), (v.baseline_ohm, r_b), (v.delta_r_ohm, delta)):
        np.testing.assert_array_equal(got, want)
        assert got.dtype == want.dtype
    assert (v.flags, v.n_baseline, v.n_pressed) == (names, n_b, n_p)


def test_fsr_label_one_press_at_the_hold_a_miss_and_two_presses():
    model, rate_hz = FsrModel(), 1000.0
    t = np.arange(8000) / rate_hz

    def volts(*onsets_s, first_n=3.0):
        force = sum((3.0 * ((t >= t0) & (t < t0 + 1.5)) for t0 in onsets_s), np.zeros_like(t))
        force[t < 1.5] *= first_n / 3.0
        return model.volts(force)

    marks = {"hold_start": 30_000}  # DAQ samples at 10 kHz: 3.0 s
    label = fsr_label(volts(2.5), rate_hz, model, 0, marks, 10_000.0)
    assert (label.onset_s, label.offset_s, label.flags, label.missed) == (2.5, 4.0, (), False)
    assert label.peak_n == pytest.approx(3.0)
    assert fsr_label(volts(), rate_hz, model, 0, marks, 10_000.0).flags == ("fsr_missed",)
    two = fsr_label(volts(0.0, 2.5, first_n=2.0), rate_hz, model, 0, marks, 10_000.0)  # labelled by the stronger
    assert (two.onset_s, two.flags) == (2.5, ("fsr_multiple:2",)) and two.peak_n == pytest.approx(3.0)
    late = fsr_label(volts(5.0), rate_hz, model, 0, marks, 10_000.0)
    assert late.flags == ("fsr_not_at_hold",) and late.onset_s == 5.0
    assert fsr_label(None, rate_hz, model, 0, marks, 10_000.0).flags == ()

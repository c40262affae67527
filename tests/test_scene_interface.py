"""Electrode and ADC variability sources of the simulated DAQ, each against its closed form:
the double layer (RMS reads |Z|, lock-in reads R), V/I sampling skew (lock-in reads R cos phi - X sin phi),
mains pickup (a line of the set amplitude at the mains frequency), and the features path against the waveforms."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.sim.daq import NoiseModel, SimulatedDAQ

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"
R_TRUE = np.linspace(2_000.0, 4_000.0, 28)
CLEAN = NoiseModel.none()


def constant(r):
    return lambda t: np.broadcast_to(r, (len(t), r.shape[0]))


@pytest.fixture(scope="module")
def sweep(paper_layout):
    return build_sweep(load_wiring(PAPER, paper_layout))


def read(sweep, noise, method, n_sweeps=2):
    daq = SimulatedDAQ(DaqConfig(), constant(R_TRUE), noise=noise)
    return demodulate(daq.acquire(sweep, n_sweeps, rng=np.random.default_rng(0)), sweep, method).resistance_ohm


def test_double_layer_rms_reads_modulus_lockin_reads_resistance(sweep):
    noise = dataclasses.replace(CLEAN, series_capacitance_f=0.5e-6)  # X = 318.3 ohm at 1 kHz
    x = 1.0 / (2 * np.pi * 1000.0 * 0.5e-6)
    assert noise.reactance_ohm(1000.0) == pytest.approx(x, rel=1e-15)
    np.testing.assert_allclose(read(sweep, noise, "rms"), np.broadcast_to(np.hypot(R_TRUE, x), (2, 28)), rtol=1e-9)
    np.testing.assert_allclose(read(sweep, noise, "lockin"), np.broadcast_to(R_TRUE, (2, 28)), rtol=1e-9)


def test_lockin_bias_under_skew_equals_the_closed_form(sweep):
    skew_s, x = 8e-6, 1.0 / (2 * np.pi * 1000.0 * 0.5e-6)
    phi = 2 * np.pi * 1000.0 * skew_s
    noise = dataclasses.replace(CLEAN, adc_skew_s=skew_s, series_capacitance_f=0.5e-6)
    expected = R_TRUE * np.cos(phi) - x * np.sin(phi)  # Re((R + iX) e^{i phi})
    np.testing.assert_allclose(read(sweep, noise, "lockin"), np.broadcast_to(expected, (2, 28)), rtol=1e-9)
    # the one-period RMS window is blind to the phase: |Z| whatever the skew
    np.testing.assert_allclose(read(sweep, noise, "rms"), np.broadcast_to(np.hypot(R_TRUE, x), (2, 28)), rtol=1e-9)
    assert np.all(expected < R_TRUE - 15.0)  # the bias is real: more than 15 ohm at 8 us


def test_mains_pickup_is_a_line_of_its_amplitude(sweep):
    noise = dataclasses.replace(CLEAN, mains_v=0.02, mains_frequency_hz=50.0)
    daq = SimulatedDAQ(DaqConfig(), constant(np.zeros(28)), noise=noise)  # a shorted load: only the hum is left
    acq = daq.acquire(sweep, 8, rng=np.random.default_rng(0))
    v = acq.voltage_v
    n = (v.size // 200) * 200  # whole 50 Hz periods at 10 kHz
    spectrum = np.abs(np.fft.rfft(v[:n])) * 2 / n
    freqs = np.fft.rfftfreq(n, 1e-4)
    assert freqs[np.argmax(spectrum)] == pytest.approx(50.0)
    assert spectrum.max() == pytest.approx(0.02, rel=1e-9)


@pytest.mark.parametrize("method", ["rms", "lockin"])
@pytest.mark.parametrize(
    "change",
    [{"series_capacitance_f": 1e-6}, {"adc_skew_s": 5e-6}, {"mains_v": 0.5}, {"mains_v": 0.5, "adc_skew_s": 5e-6}],
)
def test_features_path_reads_what_the_waveforms_read(sweep, method, change):
    noise = dataclasses.replace(CLEAN, **change)
    daq = SimulatedDAQ(DaqConfig(), constant(R_TRUE), noise=noise)
    waves = demodulate(daq.acquire(sweep, 3, rng=np.random.default_rng(0), start_time_s=0.37), sweep, method)
    feats = daq.estimate_sweep(sweep, np.random.default_rng(0), 0.37, method=method, window=10, n_sweeps=3)
    np.testing.assert_allclose(feats.resistance_ohm, waves.resistance_ohm, rtol=1e-9)
    if "mains_v" in change and method == "rms":
        assert np.max(np.abs(waves.resistance_ohm - R_TRUE)) > 1.0  # 0.5 V of hum biases the RMS


def test_an_off_source_changes_no_bit(sweep):
    base = NoiseModel()
    off = dataclasses.replace(base, series_capacitance_f=0.0, adc_skew_s=0.0, mains_v=0.0, mains_frequency_hz=60.0)
    a = SimulatedDAQ(DaqConfig(), constant(R_TRUE), noise=base).acquire(sweep, 2, rng=np.random.default_rng(3))
    b = SimulatedDAQ(DaqConfig(), constant(R_TRUE), noise=off).acquire(sweep, 2, rng=np.random.default_rng(3))
    assert a.samples.tobytes() == b.samples.tobytes()

"""The simulated DAQ's imperfections (`NoiseModel`): white noise, offsets, quantisation, clipping, switching
transients, drift, FSR spikes, and the electrode and ADC effects (double layer, V/I skew, mains pickup).

Its own module so that the DAQ (neatskin.sim.daq) and the estimator's moments (neatskin.sim.moments), which
both read it, need not import each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NoiseModel:
    """Rig imperfections of the simulated DAQ; NoiseModel.none() is an ideal instrument."""

    voltage_noise_v: float = 2e-3  # white, across the pair
    current_noise_a: float = 1e-7
    fsr_noise_v: float = 5e-3
    voltage_offset_v: float = 0.0
    current_offset_a: float = 0.0
    quantise: bool = True
    clip: bool = True
    transient_v: float = 0.2  # charge injection at each switch
    transient_tau_samples: float = 2.0
    drift_per_s: float = 0.0  # fluid resistivity drift, relative per second
    fsr_spike_rate_hz: float = 0.0  # single-sample spikes on the FSR channel (cable knocks, EMI)
    fsr_spike_v: float = 2.0  # their size: +-uniform(0.5, 1) x this
    series_capacitance_f: float = 0.0  # the electrodes' double layers in series with the pair (0 = none)
    adc_skew_s: float = 0.0  # the current channel is sampled this long after the voltage channel
    mains_v: float = 0.0  # mains pickup on the voltage channel, amplitude
    mains_frequency_hz: float = 50.0

    def reactance_ohm(self, frequency_hz: float) -> float:
        """X = 1 / (w C) of the series double layer at the excitation frequency (0 without one)."""
        if self.series_capacitance_f == 0:
            return 0.0
        return 1.0 / (2.0 * np.pi * frequency_hz * self.series_capacitance_f)

    def demodulated_resistance_ohm(self, resistance_ohm, frequency_hz: float, method: str):
        """What a noise-free demodulator reads for a pair of resistance R behind the double layer and skew:
        lock-in Re((R + iX) e^{i phi}) = R cos(phi) - X sin(phi) with phi = 2 pi f skew; RMS (whole
        periods per window) |Z| = sqrt(R^2 + X^2), which the skew does not change."""
        x = self.reactance_ohm(frequency_hz)
        r = np.asarray(resistance_ohm, float)
        if method == "lockin":
            phi = 2.0 * np.pi * frequency_hz * self.adc_skew_s
            return r * np.cos(phi) - x * np.sin(phi) if (phi or x) else r
        return np.hypot(r, x) if x else r

    @classmethod
    def none(cls) -> NoiseModel:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, False, False, 0.0, 2.0, 0.0, 0.0)

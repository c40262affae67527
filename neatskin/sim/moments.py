"""The features path's statistics: mean and spread of a demodulator's estimate under the simulated DAQ's noise model.

`estimator_moments` gives, per sweep and pair, what the waveform path's RMS or lock-in estimate would
average to and how it would scatter (docs/acquisition.md gives the formulas), so `SimulatedDAQ.estimate_sweep`
can draw the estimate without generating waveforms. Pure functions of the resistances, the sweep, the DAQ
configuration and the noise model; `_sine` is the shared sine table of the DAQ's excitation.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from neatskin.acquisition import demod
from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.demod import window_counts
from neatskin.acquisition.sequence import Sweep
from neatskin.sim.noise import NoiseModel


def effective_noise_var(config: DaqConfig, noise: NoiseModel) -> tuple[float, float]:
    """Variance of the white noise on V and I (physical units), quantisation (lsb^2 / 12) included."""
    lsb_phys = config.lsb_ai_v * config.to_physical
    q = lsb_phys**2 / 12 if noise.quantise else np.zeros(3)
    return noise.voltage_noise_v**2 + float(q[0]), noise.current_noise_a**2 + float(q[1])


def estimator_moments(
    resistance_ohm: np.ndarray,
    sweep: Sweep,
    config: DaqConfig,
    noise: NoiseModel,
    method: str = "lockin",
    window: int = 10,
    start_sample: int = 0,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean and std of one sweep's estimate of each pair under the noise model, and the demodulator's block count.

    resistance_ohm: (sweeps, pairs) true values (finite, unclipped). Pure: the analytic statistics the
    features-only path draws from (docs/acquisition.md gives the formulas).
    """
    r = np.asarray(resistance_ohm, dtype=float)
    amp = config.amplitude_a
    sigma_v2, sigma_i2 = effective_noise_var(config, noise)
    v0 = r * amp
    n_live = sweep.timing.live_samples
    rel_lin = sigma_v2 / v0**2 + sigma_i2 / amp**2
    if method == "lockin":
        mean = r
        rel_var = 2.0 / n_live * rel_lin
        blocks = max(1, n_live // max(1, int(round(config.samples_per_period))))
    else:
        first = start_sample + np.arange(r.shape[0])[:, None] * sweep.n_samples + sweep.live_windows[None, :, 0]
        c = demod.window_counts(n_live, window)
        n_win = n_live - window + 1
        s = _weighted_sin2_sums(first, config.samples_per_period, n_live, window)
        dc_v2, dc_i2 = noise.voltage_offset_v**2, noise.current_offset_a**2
        mean = np.sqrt((v0**2 / 2 + sigma_v2 + dc_v2) / (amp**2 / 2 + sigma_i2 + dc_i2))  # RMS rectifies
        rel_var = 4.0 / (window * n_win) ** 2 * s * rel_lin + 2.0 * (c**2).sum() / (window * n_win) ** 2 * (
            sigma_v2**2 / v0**4 + sigma_i2**2 / amp**4
        )
        blocks = max(1, n_live // window)
    return mean, r * np.sqrt(rel_var), blocks


def _weighted_sin2_sums(first: np.ndarray, samples_per_period: float, n_live: int, window: int) -> np.ndarray:
    """sum_k c_k^2 sin^2 over each live window starting at sample `first` (any shape), c the moving windows'
    sample counts. With a whole number of samples per period it depends only on first mod the period: looked
    up from one row per phase, each summed as the full computation sums it (the same bits)."""
    whole = round(samples_per_period)
    if abs(samples_per_period - whole) >= 1e-9:
        return _sin2_sums(first[..., None] + np.arange(n_live), samples_per_period, n_live, window)
    return _phase_sin2_sums(whole, n_live, window)[first % whole]


def _sin2_sums(index: np.ndarray, samples_per_period: float, n_live: int, window: int) -> np.ndarray:
    return (window_counts(n_live, window) ** 2 * _sine(index, samples_per_period) ** 2).sum(axis=-1)


@lru_cache(maxsize=16)
def _phase_sin2_sums(whole: int, n_live: int, window: int) -> np.ndarray:
    sums = _sin2_sums(np.arange(whole)[:, None] + np.arange(n_live), whole, n_live, window)  # (phases,)
    sums.flags.writeable = False
    return sums


def _sine(index: np.ndarray, samples_per_period: float, phase: float = 0.0) -> np.ndarray:
    """sin(2 pi index / samples_per_period + phase), from a table when a period is a whole number of samples."""
    whole = round(samples_per_period)
    if abs(samples_per_period - whole) < 1e-9:
        table = (
            np.sin(2 * np.pi * np.arange(whole) / whole + phase)
            if phase
            else np.sin(2 * np.pi * np.arange(whole) / whole)
        )
        return table[index % whole]
    if phase:
        return np.sin(2 * np.pi * index / samples_per_period + phase)
    return np.sin(2 * np.pi * index / samples_per_period)

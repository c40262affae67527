"""Demodulation to resistance per pair: the paper's moving RMS and Ohm's law, and a lock-in against the known excitation.

Both use each pair's live window only (settle samples discarded), vectorised over
(sweeps, pairs, samples).

- "rms": moving RMS of V and I over `window` samples (10 in the paper: one excitation
  period at 10 kHz), R_t = rms_V / rms_I, R = mean of R_t over the live window;
  uncertainty = std of R_t at non-overlapping positions / sqrt(their count).
- "lockin": V and I projected on exp(-i w t) over the live window, R = Re(Z_V / Z_I);
  uncertainty = std of the same ratio over one-period blocks / sqrt(blocks).

Flags: OPEN_CIRCUIT when the current RMS is below open_fraction of the excitation's RMS
(resistance and uncertainty = +inf, no division by zero); CLIPPED when any live V or I
sample reaches the AI range, or when the mux's switch node, v + i x mux_series_ohm (the
wiring's 2 R_on + mismatch in series with the pair), reaches a mux rail: at a live sample, or
at the sine's peak between samples (sqrt(2) x its RMS over the live window), so the rig flags
exactly the readings with amplitude x (R + series) >= the rail (DaqConfig.rail_ohm); DC_OFFSET when the mean of V or I exceeds DC_OFFSET_SHARE of
its AC RMS and one ADC step (the RMS estimate is then biased; the lock-in is not).
"""

from __future__ import annotations

import numpy as np

from neatskin.acquisition.daq.base import Acquisition
from neatskin.acquisition.estimates import PairEstimates, PairFlag
from neatskin.acquisition.sequence import Sweep
from neatskin.errors import ConfigError

METHODS = ("rms", "lockin")
DC_OFFSET_SHARE = 0.05
OPEN_FRACTION = 0.05


def check_method(method: str, window: int, sweep: Sweep) -> None:
    if method not in METHODS:
        raise ConfigError(
            f"unknown demodulation {method!r}", field="demodulation", fix=f"use one of {', '.join(METHODS)}"
        )
    if method == "rms" and not (isinstance(window, (int, np.integer)) and 1 <= window <= sweep.timing.live_samples):
        raise ConfigError(
            f"RMS window {window!r} does not fit the live window of {sweep.timing.live_samples} samples",
            field="window",
            fix="set 1 <= window <= live_samples (10 = one 1 kHz period at 10 kHz)",
        )


def window_counts(n: int, window: int) -> np.ndarray:
    """How many of the n - window + 1 moving windows contain each of n samples, (n,)."""
    k = np.arange(n)
    return (np.minimum(k, n - window) - np.maximum(k - window + 1, 0) + 1).astype(float)


def live_rows(acq: Acquisition, sweep: Sweep) -> np.ndarray:
    """(sweeps, pairs, live_samples) row indices of every live sample in the acquisition."""
    if acq.n_samples != acq.n_sweeps * sweep.n_samples:
        raise ConfigError(
            f"the acquisition has {acq.n_samples} samples, not {acq.n_sweeps} sweeps of {sweep.n_samples}",
            field="sweep",
            fix="demodulate with the sweep it was acquired with",
        )
    return np.arange(acq.n_sweeps)[:, None, None] * sweep.n_samples + sweep.live_sample_index[None]


def demodulate(
    acq: Acquisition, sweep: Sweep, method: str = "lockin", window: int = 10, open_fraction: float = OPEN_FRACTION
) -> PairEstimates:
    """Resistance per (sweep, pair) from an acquisition of whole sweeps."""
    check_method(method, window, sweep)
    cfg = acq.config
    rows = live_rows(acq, sweep)
    v = acq.samples[rows, 0]
    i = acq.samples[rows, 1]
    index = acq.sample_index[rows]
    windows = np.stack([index[..., 0], index[..., -1] + 1], axis=-1)
    rms_i = np.sqrt(np.mean(i * i, axis=-1))
    open_circuit = ~(rms_i > open_fraction * cfg.amplitude_a / np.sqrt(2))  # NaN-safe
    if method == "rms":
        r, u = _rms(v, i, window, open_circuit)
    else:
        r, u = _lockin(v, i, index, cfg.samples_per_period, open_circuit)
    flags = np.zeros(r.shape, dtype=np.uint8)
    flags[open_circuit] |= np.uint8(PairFlag.OPEN_CIRCUIT)
    lsb = cfg.lsb_ai_v * cfg.to_physical
    clipped = (np.abs(v) >= cfg.voltage_limit_v - lsb[0]).any(-1) | (np.abs(i) >= cfg.current_limit_a - lsb[1]).any(-1)
    flags[clipped | at_rail(v, i, cfg)] |= np.uint8(PairFlag.CLIPPED)
    dc = _dc_offset(v, lsb[0]) | _dc_offset(i, lsb[1])
    flags[dc & ~open_circuit] |= np.uint8(PairFlag.DC_OFFSET)
    r = np.where(open_circuit, np.inf, r)
    u = np.where(open_circuit, np.inf, u)
    return PairEstimates(r, u, flags, windows, method)


def at_rail(v: np.ndarray, i: np.ndarray, cfg) -> np.ndarray:
    """(sweeps, pairs) whether the switch node v + i x mux_series_ohm reached a mux rail (within one ADC step):
    a live sample at it, or the sine through the samples peaking at it (sqrt(2) RMS: exact for whole periods)."""
    lsb = cfg.node_lsb_v
    node = v + i * cfg.mux_series_ohm
    sample = ((node >= cfg.rail_positive_v - lsb) | (node <= cfg.rail_negative_v + lsb)).any(-1)
    peak = np.sqrt(2.0 * np.mean(node * node, axis=-1))
    return sample | (peak >= cfg.rail_v - lsb)


def _dc_offset(x: np.ndarray, lsb: float) -> np.ndarray:
    """|mean| above DC_OFFSET_SHARE of the AC RMS, and above one ADC step (an offset below it is not measurable)."""
    mean = x.mean(axis=-1)
    ac = np.sqrt(np.maximum((x * x).mean(axis=-1) - mean**2, 0.0))
    return np.abs(mean) > np.maximum(DC_OFFSET_SHARE * ac, lsb)


def _safe_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    ok = np.abs(den) > 0
    return np.where(ok, num / np.where(ok, den, 1.0), np.inf)


def _rms(v: np.ndarray, i: np.ndarray, window: int, open_circuit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    def moving_ms(x):
        c = np.cumsum(x * x, axis=-1)
        c = np.concatenate([np.zeros(x.shape[:-1] + (1,)), c], axis=-1)
        return np.maximum(c[..., window:] - c[..., :-window], 0.0) / window

    ms_v, ms_i = moving_ms(v), moving_ms(i)
    r_t = np.sqrt(_safe_ratio(ms_v, ms_i))
    r_t = np.where(open_circuit[..., None], 0.0, r_t)
    r = r_t.mean(axis=-1)
    independent = r_t[..., ::window]
    k = independent.shape[-1]
    u = independent.std(axis=-1, ddof=1) / np.sqrt(k) if k > 1 else r_t.std(axis=-1)
    return np.where(np.isfinite(r), r, np.inf), np.where(np.isfinite(u), u, np.inf)


def _lockin(v, i, index, samples_per_period: float, open_circuit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    whole = round(samples_per_period)
    if abs(samples_per_period - whole) < 1e-9:  # exact phase for large indices, from a table
        table = 2 * np.pi * np.arange(whole) / whole
        ref = np.stack([np.cos(table), np.sin(table)])[:, index % whole]
    else:
        phase = 2 * np.pi * index / samples_per_period
        ref = np.stack([np.cos(phase), np.sin(phase)])
    # products[a, b] = signal a (V, I) times reference b (cos, sin): one pass over the samples
    products = np.stack([v, i])[:, None] * ref[None]  # (2, 2, sweeps, pairs, N)
    period = max(1, int(whole))
    n = v.shape[-1]
    blocks = n // period
    cut = blocks * period
    block_sums = products[..., :cut].reshape(products.shape[:-1] + (blocks, period)).sum(-1)
    totals = block_sums.sum(-1) + products[..., cut:].sum(-1)
    (vc, vs), (ic, is_) = totals
    r = _safe_ratio(vc * ic + vs * is_, ic * ic + is_ * is_)  # Re(Zv / Zi)
    if blocks > 1:
        (bvc, bvs), (bic, bis) = block_sums
        with np.errstate(invalid="ignore"):
            rb = _safe_ratio(bvc * bic + bvs * bis, bic * bic + bis * bis)
            u = rb.std(axis=-1, ddof=1) / np.sqrt(blocks)
    else:
        u = np.zeros(r.shape)
    r = np.where(open_circuit, 0.0, r)
    u = np.where(open_circuit | ~np.isfinite(u), np.where(open_circuit, 0.0, np.inf), u)
    return np.where(np.isfinite(r), r, np.inf), u

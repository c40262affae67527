"""The simulated DAQ: voltage, current and FSR waveforms of whole sweeps from the skin's pair resistances, and a features-only fast path.

It does not know the skin: the caller gives `pair_resistance_ohm(times_s) -> (n_times, pairs)`
and `force_n(times_s) -> (n_times,)` (the rig passes its skin model and probe trajectory).

Waveform path, per sample n at t = index / rate_hz (vectorised, no loop per sample):
  i = clip(A sin(2 pi f t), +-compliance / R) through the live pair (0 while inhibited;
      an open pair, R = inf, drives the galvanostat to its compliance rail with no current)
  v = i R (R times the fluid drift 1 + drift_per_s * t) + a switching transient
      transient_v * exp(-k / transient_tau_samples) k samples after the switch closes
  + DC offsets, white noise, range clipping and ADC quantisation in AI volts;
  fsr = Vcc F / (F + k / Rm) + noise (+ optional single-sample spikes), clipped and quantised.
Electrode and ADC effects (NoiseModel, each off at 0 and then untouched, bit for bit): the
double layers as a series capacitance (v += -A X cos(wt): RMS reads |Z|, lock-in reads R),
V/I sampling skew (the current channel read `adc_skew_s` late: the lock-in reads
R cos(phi) - X sin(phi)), and mains pickup on the voltage channel.
By default R is evaluated once per pair per sweep, at the middle of its live window
(resistance_sampling="per_pair"); "per_sample" evaluates it at every sample.

The mux rails (DaqConfig.rail_*_v, the wiring's): where i (R + mux_series_ohm) would pass a rail the switch
clamps, V across the pair is rail R / (R + series) while I reads the galvanostat's current (`_clamp_at_rails`);
the demodulator flags it CLIPPED.

Features-only path (`estimate_sweep`): the estimate the demodulator would return, drawn
from the estimator's analytic mean and standard deviation under this noise model (see
docs/acquisition.md) — no waveform. Pairs that would clip, hit compliance, come near a mux
rail or be open fall back to the waveform path, so flags and values stay the waveform path's.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from neatskin.acquisition import demod
from neatskin.acquisition.daq.base import Acquisition, Daq, DaqConfig
from neatskin.acquisition.estimates import PairEstimates, PairFlag
from neatskin.acquisition.fsr import FsrModel
from neatskin.acquisition.sequence import Sweep
from neatskin.errors import ConfigError
from neatskin.sim.moments import _sine, effective_noise_var, estimator_moments
from neatskin.sim.noise import NoiseModel

ResistanceSource = Callable[[np.ndarray], np.ndarray]
SlotResistanceSource = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (times, pair index) -> (times,)
ForceSource = Callable[[np.ndarray], np.ndarray]


def _no_force(times_s: np.ndarray) -> np.ndarray:
    return np.zeros(np.shape(times_s))


class SimulatedDAQ(Daq):
    """Waveforms of whole sweeps at the configured rate from callables for the skin and the probe force."""

    def __init__(
        self,
        config: DaqConfig,
        pair_resistance_ohm: ResistanceSource,
        force_n: ForceSource | None = None,
        noise: NoiseModel = NoiseModel(),
        fsr: FsrModel = FsrModel(),
        resistance_sampling: str = "per_pair",
        slot_resistance_ohm: SlotResistanceSource | None = None,
    ) -> None:
        if resistance_sampling not in ("per_pair", "per_sample"):
            raise ConfigError(
                f"unknown resistance_sampling {resistance_sampling!r}",
                field="resistance_sampling",
                fix="use 'per_pair' or 'per_sample'",
            )
        self.config = config
        self.pair_resistance_ohm = pair_resistance_ohm
        self.force_n = force_n or _no_force
        self.noise = noise
        self.fsr = fsr
        self.resistance_sampling = resistance_sampling
        # optional: each time's own pair only, the values pair_resistance_ohm(times)[k, pair[k]] would give
        self.slot_resistance_ohm = slot_resistance_ohm

    # ---- shared pieces --------------------------------------------------------------------

    def _start(self, start_time_s: float) -> int:
        return int(round(start_time_s * self.config.rate_hz))

    def _slot_resistance(self, sweep: Sweep, n_sweeps: int, start: int) -> np.ndarray:
        """(sweeps, pairs) resistance of each pair at the middle of its live window, drift included."""
        mid = sweep.live_windows.mean(axis=1)  # (pairs,)
        t = (start + np.arange(n_sweeps)[:, None] * sweep.n_samples + mid[None, :]) / self.config.rate_hz
        if self.slot_resistance_ohm is not None:
            pairs = np.broadcast_to(np.arange(sweep.n_pairs), t.shape).reshape(-1)
            r = np.asarray(self.slot_resistance_ohm(t.ravel(), pairs), dtype=float).reshape(t.shape)
            return r * (1.0 + self.noise.drift_per_s * t)
        r_all = np.asarray(self.pair_resistance_ohm(t.ravel()), dtype=float)
        if r_all.shape != (t.size, sweep.n_pairs):
            raise ConfigError(
                f"pair_resistance_ohm returned shape {r_all.shape}, expected {(t.size, sweep.n_pairs)}",
                field="pair_resistance_ohm",
                fix="return (n_times, pairs) in layout.pairs order",
            )
        r = r_all.reshape(n_sweeps, sweep.n_pairs, sweep.n_pairs)[:, np.arange(sweep.n_pairs), np.arange(sweep.n_pairs)]
        return r * (1.0 + self.noise.drift_per_s * t)

    # ---- waveform path ----------------------------------------------------------------

    def acquire(
        self, sweep: Sweep, n_sweeps: int = 1, *, rng: np.random.Generator | None = None, start_time_s: float = 0.0
    ) -> Acquisition:
        cfg, noise = self.config, self.noise
        if abs(sweep.rate_hz - cfg.rate_hz) > 1e-9:
            raise ConfigError(
                f"sweep built at {sweep.rate_hz} Hz, DAQ configured at {cfg.rate_hz} Hz",
                field="rate_hz",
                fix="build the sweep with the DAQ's rate",
            )
        if not isinstance(rng, np.random.Generator):
            raise ConfigError(
                "the simulated DAQ needs an explicit rng (numpy.random.Generator)",
                field="rng",
                fix="pass rng=numpy.random.default_rng(seed), keyed by (seed, press) so a resumed "
                "campaign draws the same numbers",
            )
        start = self._start(start_time_s)
        n = n_sweeps * sweep.n_samples
        index = start + np.arange(n, dtype=np.int64)
        t = index / cfg.rate_hz
        pair, sweep_of, connected, transient = self._static(sweep, n_sweeps)
        if self.resistance_sampling == "per_pair":
            r_slot = self._slot_resistance(sweep, n_sweeps, start)
            r = r_slot[sweep_of, pair]
        else:
            r_all = np.asarray(self.pair_resistance_ohm(t), dtype=float)
            r = r_all[np.arange(n), pair] * (1 + noise.drift_per_s * t)
        command = cfg.amplitude_a * _sine(index, cfg.samples_per_period) * connected
        physical = np.empty((n, 3))
        i_max = None
        if np.all(np.isfinite(r)) and np.all(r >= 0) and float(np.max(r)) * cfg.amplitude_a <= cfg.compliance_v:
            current = command  # the common case: the galvanostat drives the full sine
            np.multiply(current, r, out=physical[:, 0])
        else:
            finite = np.isfinite(r) & (r >= 0)
            with np.errstate(divide="ignore"):
                i_max = np.where(finite, cfg.compliance_v / np.where(finite, r, 1.0), 0.0)
            i_max = np.where(finite & (r == 0), np.inf, i_max)
            current = np.clip(command, -i_max, i_max)
            physical[:, 0] = np.where(finite, current * np.where(finite, r, 0.0), cfg.compliance_v * np.sign(command))
        physical[:, 1] = current
        self._clamp_at_rails(physical, r, current)
        self._add_interface_effects(physical, index, connected, i_max)
        if noise.transient_v:
            physical[:, 0] += transient
        if noise.voltage_offset_v:
            physical[:, 0] += noise.voltage_offset_v * connected
        if noise.current_offset_a:
            physical[:, 1] += noise.current_offset_a * connected
        physical[:, 2] = self.fsr.volts(np.asarray(self.force_n(t), dtype=float))
        std = np.array([noise.voltage_noise_v, noise.current_noise_a, noise.fsr_noise_v])
        if np.any(std > 0):
            physical += rng.standard_normal((n, 3)) * std
        if noise.fsr_spike_rate_hz > 0:
            k = rng.poisson(noise.fsr_spike_rate_hz * n / cfg.rate_hz)
            where = rng.integers(0, n, k)
            physical[where, 2] += rng.choice([-1.0, 1.0], k) * rng.uniform(0.5, 1.0, k) * noise.fsr_spike_v
        return Acquisition(self._digitise(physical), index, cfg, n_sweeps)

    def _clamp_at_rails(self, physical: np.ndarray, r: np.ndarray, current: np.ndarray) -> None:
        """The mux rails, in place: the switch node on the galvanostat's side sits at i (R + mux_series_ohm); where
        it would pass a rail the switch's protection diodes hold it there, the skin takes rail / (R + series) and
        the excess goes into the rail, so V across the pair is rail R / (R + series) while the current monitor
        still reads the galvanostat's i (the demodulator flags it CLIPPED). A cut pair (R = inf) keeps its model:
        the galvanostat at compliance with no current (the diodes' path left out; it reads OPEN_CIRCUIT | CLIPPED
        either way). Off when no finite R reaches `rail_ohm`: then no bit changes."""
        cfg = self.config
        finite = np.isfinite(r) & (r >= 0)
        r_finite = np.where(finite, r, 0.0)
        if not finite.any() or float(r_finite.max()) <= cfg.rail_ohm:
            return
        path = r_finite + cfg.mux_series_ohm
        node = current * path
        over = finite & ((node > cfg.rail_positive_v) | (node < cfg.rail_negative_v))
        if over.any():
            held = np.clip(node[over], cfg.rail_negative_v, cfg.rail_positive_v)
            physical[over, 0] = held * r_finite[over] / path[over]

    def _add_interface_effects(self, physical, index, connected, i_max) -> None:
        """Double layer (V += (1 / C) integral of i dt, steady state), V/I sampling skew (I read skew later)
        and mains pickup, in place; each skipped when off, so an off effect changes no bit."""
        cfg, noise = self.config, self.noise
        if noise.series_capacitance_f:
            # i = A sin(wt) through C gives -A X cos(wt) = A X sin(wt - pi/2)
            x = noise.reactance_ohm(cfg.frequency_hz)
            physical[:, 0] += x * cfg.amplitude_a * _sine(index, cfg.samples_per_period, -0.5 * np.pi) * connected
        if noise.adc_skew_s:
            shift = 2.0 * np.pi * cfg.frequency_hz * noise.adc_skew_s
            skewed = cfg.amplitude_a * _sine(index, cfg.samples_per_period, shift) * connected
            physical[:, 1] = skewed if i_max is None else np.clip(skewed, -i_max, i_max)
        if noise.mains_v:
            physical[:, 0] += noise.mains_v * _sine(index, cfg.rate_hz / noise.mains_frequency_hz)

    def _static(self, sweep: Sweep, n_sweeps: int):
        """Per-sample arrays that depend only on the sweep (cached for the last sweep used)."""
        key = (id(sweep), n_sweeps, self.noise.transient_v, self.noise.transient_tau_samples)
        cached = getattr(self, "_static_cache", None)
        if cached is not None and cached[0] == key and cached[1] is sweep:
            return cached[2]
        pair_raw = np.tile(sweep.pair_of_sample, n_sweeps)
        connected = (pair_raw >= 0).astype(float)
        pair = np.maximum(pair_raw, 0)
        sweep_of = np.repeat(np.arange(n_sweeps), sweep.n_samples)
        since = np.tile(np.arange(sweep.n_samples) - _switch_sample(sweep), n_sweeps)
        transient = (
            self.noise.transient_v * np.exp(-np.maximum(since, 0) / self.noise.transient_tau_samples) * connected
        )
        value = (pair, sweep_of, connected, transient)
        self._static_cache = (key, sweep, value)
        return value

    def _digitise(self, physical: np.ndarray) -> np.ndarray:
        """Physical units -> AI volts, clipped to the ranges and rounded to the ADC step, -> physical (in place)."""
        cfg = self.config
        physical /= cfg.to_physical
        if self.noise.clip:
            ranges = np.array([cfg.voltage_range_v, cfg.current_range_v, cfg.fsr_range_v])
            np.clip(physical, -ranges, ranges, out=physical)
        if self.noise.quantise:
            lsb = cfg.lsb_ai_v
            physical /= lsb
            np.round(physical, out=physical)
            physical *= lsb
        physical *= cfg.to_physical
        return physical

    # ---- features-only path -----------------------------------------------------------

    def estimate_sweep(
        self,
        sweep: Sweep,
        rng: np.random.Generator,
        start_time_s: float = 0.0,
        method: str = "lockin",
        window: int = 10,
        n_sweeps: int = 1,
    ) -> PairEstimates:
        """Per-pair estimates with the waveform path's statistics, without generating waveforms."""
        demod.check_method(method, window, sweep)
        cfg, noise = self.config, self.noise
        start = self._start(start_time_s)
        r = self._slot_resistance(sweep, n_sweeps, start)  # (sweeps, pairs)
        windows = start + np.arange(n_sweeps)[:, None, None] * sweep.n_samples + sweep.live_windows[None]
        amp = cfg.amplitude_a
        peak_v = np.abs(r) * amp + abs(noise.voltage_offset_v)
        peak_i = amp + abs(noise.current_offset_a)
        exact = (
            np.isfinite(r)
            & (r > 0)
            & (r * amp < cfg.compliance_v)
            & ((peak_v < cfg.voltage_limit_v) | (not noise.clip))
            & ((peak_i < cfg.current_limit_a) | (not noise.clip))
            & (amp * (np.abs(r) + cfg.mux_series_ohm) + self._rail_margin_v(sweep) < cfg.rail_v)
        )
        cut = ~np.isfinite(r) & self._surely_open_and_clipped()
        if not (exact | cut).all():
            acq = self.acquire(sweep, n_sweeps, rng=rng, start_time_s=start_time_s)
            return demod.demodulate(acq, sweep, method=method, window=window)
        if cut.any():  # a pair cut off: the waveform path's reading without its waveforms (see _open_estimate)
            r = np.where(cut, 1.0, r)
        if noise.mains_v:
            r = self._noise_free_estimate(r, windows, method, window)
        elif noise.series_capacitance_f or noise.adc_skew_s:
            r = noise.demodulated_resistance_ohm(r, cfg.frequency_hz, method)
        mean, std, blocks = estimator_moments(r, sweep, cfg, noise, method, window, start)
        v0 = r * amp
        resistance = mean + std * rng.standard_normal(r.shape)
        # the demodulator's uncertainty is std / sqrt(blocks) of `blocks` block estimates: a chi spread
        spread = np.sqrt(rng.chisquare(max(blocks - 1, 1), r.shape) / max(blocks - 1, 1)) if blocks > 1 else 1.0
        uncertainty = std * spread
        flags = np.zeros(r.shape, dtype=np.uint8)
        dc_share = demod.DC_OFFSET_SHARE  # the demodulator's rule, on the noise-free means
        lsb = cfg.lsb_ai_v * cfg.to_physical
        dc = (abs(noise.voltage_offset_v) > np.maximum(dc_share * v0 / np.sqrt(2), lsb[0])) | (
            abs(noise.current_offset_a) > max(dc_share * amp / np.sqrt(2), lsb[1])
        )
        flags[dc] |= np.uint8(PairFlag.DC_OFFSET)
        if cut.any():
            resistance = np.where(cut, np.inf, resistance)
            uncertainty = np.where(cut, np.inf, uncertainty)
            flags[cut] = np.uint8(PairFlag.OPEN_CIRCUIT | PairFlag.CLIPPED)
        return PairEstimates(resistance, uncertainty, flags, windows, method)

    def _rail_margin_v(self, sweep: Sweep) -> float:
        """What could lift the demodulator's switch-node reading (v + i x mux_series_ohm) above i (R + series):
        offsets, double layer, mains, the switching transient where the live window starts (settle_samples after
        the switch) and 6 sigma of noise, plus one ADC step. A pair within it of a rail goes to the waveform path,
        which clamps and flags exactly as the rig would."""
        cfg, noise = self.config, self.noise
        s = cfg.mux_series_ohm
        return (
            abs(noise.voltage_offset_v)
            + s * abs(noise.current_offset_a)
            + noise.reactance_ohm(cfg.frequency_hz) * cfg.amplitude_a
            + noise.mains_v
            + abs(noise.transient_v) * float(np.exp(-sweep.timing.settle_samples / noise.transient_tau_samples))
            + 6.0 * float(np.hypot(noise.voltage_noise_v, s * noise.current_noise_a))
            + cfg.node_lsb_v
        )

    def _surely_open_and_clipped(self) -> bool:
        """Whether a cut pair (R = inf) surely reads as the waveform path reads it: the galvanostat at its
        compliance drives no current, so the current's RMS (offset and noise, 6 sigma) stays below the
        demodulator's open-circuit threshold, and the voltage at the compliance rail, less every addition that
        could pull it back (offset, double layer, mains, transient, 6 sigma of noise), still reaches the AI range:
        flags OPEN_CIRCUIT | CLIPPED, R and its uncertainty inf (demod.demodulate). Else the waveform path decides."""
        cfg, noise = self.config, self.noise
        amp = cfg.amplitude_a
        current = abs(noise.current_offset_a) + 6.0 * noise.current_noise_a
        margin = (
            abs(noise.voltage_offset_v)
            + noise.reactance_ohm(cfg.frequency_hz) * amp
            + noise.mains_v
            + abs(noise.transient_v)
            + 6.0 * noise.voltage_noise_v
        )
        lsb = float(cfg.lsb_ai_v[0] * cfg.to_physical[0])
        return bool(
            noise.clip
            and current < 0.5 * demod.OPEN_FRACTION * amp / np.sqrt(2)
            and cfg.compliance_v - margin >= cfg.voltage_limit_v + lsb
        )

    def _noise_free_estimate(self, r: np.ndarray, windows: np.ndarray, method: str, window: int) -> np.ndarray:
        """What the demodulator reads from the noise-free live samples (double layer, skew and mains
        included): the mains hum has no closed form under a moving RMS, so its bias is computed on
        the live windows alone, not on whole waveforms."""
        cfg = self.config
        index = windows[..., :1] + np.arange(windows[0, 0, 1] - windows[0, 0, 0])  # (sweeps, pairs, live)
        flat = index.reshape(-1)
        physical = np.empty((flat.size, 3))
        current = cfg.amplitude_a * _sine(flat, cfg.samples_per_period)
        physical[:, 0] = current * np.repeat(r.reshape(-1), index.shape[-1])
        physical[:, 1] = current
        self._add_interface_effects(physical, flat, np.ones(flat.size), None)
        v = physical[:, 0].reshape(index.shape)
        i = physical[:, 1].reshape(index.shape)
        closed = np.zeros(r.shape, dtype=bool)
        if method == "rms":
            mean, _ = demod._rms(v, i, window, closed)
        else:
            mean, _ = demod._lockin(v, i, index, cfg.samples_per_period, closed)
        return mean

    def effective_noise_var(self) -> tuple[float, float]:
        return effective_noise_var(self.config, self.noise)


def _switch_sample(sweep: Sweep) -> np.ndarray:
    """(samples,) the sample at which the current slot's switch closed."""
    slot_len = sweep.timing.slot_samples
    return (np.arange(sweep.n_samples) // slot_len) * slot_len + sweep.timing.break_samples

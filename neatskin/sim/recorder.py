"""The dry run's recorder: a press's acquisition, the simulated skin sampled along the simulated printer's trajectory.

The printer runs on a virtual clock, so the acquisition is computed after the motion from the
printer's own trajectory; its sample clock is keyed by the press (press_id * PRESS_SLOT_S), and
its random draws by (seed, press_id), so a resumed campaign records bit for bit what an
uninterrupted one would have. The probe it samples, with the scene's per-press variability
(`PressConditions`: placement, depth jitter, drift, dents of earlier presses, a pure function of
the press id), is `neatskin.sim.dryprobe`'s; the random streams are numbered here.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.record import PendingPress, PressRecord
from neatskin.sim.deferred import DeferredRecord, EstimateJob, EstimateQueue
from neatskin.sim.dryprobe import DryProbe
from neatskin.sim.fsrnoise import STREAM_FSR as STREAM_FSR  # re-exported: the streams are numbered here
from neatskin.sim.fsrnoise import FsrNoiseAhead

PRESS_SLOT_S = 1000.0  # each press owns [press_id * slot, (press_id + 1) * slot) of the dry run's sample clock
STREAM_DAQ = 1
STREAM_PLACEMENT = 2
STREAM_DEPTH = 4
FSR_DECIMATION = 10  # features-only scene: the FSR trace at rate / 10


def features_estimates(daq, sweep, press_id: int, n_sweeps: int, *, seed: int, method: str, window: int):
    """The features-only scene's pair estimates of a press, read by `daq` from the probe that has loaded the
    press's moves: the one computation the inline recorder and the skin worker (neatskin.sim.skinworker) share,
    on the stream keyed by (seed, press_id)."""
    rng = np.random.default_rng([seed, press_id, STREAM_DAQ])
    return daq.estimate_sweep(sweep, rng, press_id * PRESS_SLOT_S, method=method, window=window, n_sweeps=n_sweeps)


class SimulatedRecorder:
    """Dry-run recorder: computes the press's acquisition from the simulated printer's trajectory.

    `end` returns the press's `PendingPress`: inline, the whole PressRecord (already done); with a skin worker
    (neatskin.sim.skinworker, features scene only), a DeferredRecord whose FSR trace is computed at once and
    whose pair estimates the worker's process computes once the press is kept."""

    def __init__(
        self,
        daq,
        sweep,
        probe: DryProbe,
        clock: Callable[[], float],
        *,
        seed: int,
        signal: str,
        method: str,
        window: int,
        fsr_enabled: bool,
        keep_waveforms: bool,
        worker: EstimateQueue | None = None,
    ) -> None:
        if worker is not None and signal != "features":
            raise ValueError("a skin worker computes the features scene only; the waveforms scene stays inline")
        self.daq, self.sweep, self.probe, self.clock = daq, sweep, probe, clock
        self.seed, self.signal, self.method, self.window = seed, signal, method, window
        self.fsr_enabled, self.keep_waveforms = fsr_enabled, keep_waveforms
        self.worker = worker
        self._press: int | None = None
        self._fsr_noise: FsrNoiseAhead | None = None

    def close(self) -> None:
        """End the FSR noise's drawing thread (the rig's closers call this)."""
        if self._fsr_noise is not None:
            self._fsr_noise.close()

    def begin(self, press_id: int, n_sweeps: int) -> None:
        self._press, self._n_sweeps = press_id, n_sweeps
        self._t0 = self.clock()
        self._marks: dict[str, float] = {}

    def mark(self, name: str) -> None:
        self._marks[name] = self.clock()

    def _load(self) -> tuple[int, int, int, int]:
        """Load the press's moves into the probe: (press_id, sweeps, first sample, samples)."""
        if self._press is None:
            raise RuntimeError("end() without begin()")
        press_id, n_sweeps, sweep = self._press, self._n_sweeps, self.sweep
        daq_t0 = press_id * PRESS_SLOT_S
        self.probe.load(press_id, self._t0, daq_t0, n_sweeps * sweep.duration_s)
        return press_id, n_sweeps, int(round(daq_t0 * sweep.rate_hz)), n_sweeps * sweep.n_samples

    def _sample_marks(self, first: int) -> dict[str, int]:
        return {k: first + int(round((t - self._t0) * self.sweep.rate_hz)) for k, t in self._marks.items()}

    def end(self) -> PendingPress:
        if self.worker is not None:  # the worker's probe holds the conditions (dents, drift) this one leaves out
            return self._end_deferred(self.worker)
        press_id, n_sweeps, first, n = self._load()
        sweep, rate = self.sweep, self.sweep.rate_hz
        daq_t0 = press_id * PRESS_SLOT_S
        waveforms = fsr_v = None
        if self.signal == "waveforms":
            rng = np.random.default_rng([self.seed, press_id, STREAM_DAQ])
            acq = self.daq.acquire(sweep, n_sweeps, rng=rng, start_time_s=daq_t0)
            estimates = demodulate(acq, sweep, method=self.method, window=self.window)
            fsr_v = acq.fsr_v if self.fsr_enabled else None
            if self.keep_waveforms:
                waveforms = {
                    "voltage_v": acq.voltage_v.astype(np.float32),
                    "current_a": acq.current_a.astype(np.float32),
                    "fsr_v": acq.fsr_v.astype(np.float32),
                }
        else:
            estimates = features_estimates(
                self.daq, sweep, press_id, n_sweeps, seed=self.seed, method=self.method, window=self.window
            )
            if self.fsr_enabled:
                fsr_v = self._fsr_trace(first, n, press_id)
        marks = self._sample_marks(first)
        self._press = None
        fsr_rate = rate if self.signal == "waveforms" else rate / FSR_DECIMATION
        return PressRecord(estimates, first, n, rate, marks, fsr_v, waveforms, fsr_rate)

    def _end_deferred(self, worker: EstimateQueue) -> DeferredRecord:
        """The press's FSR trace and marks now (the runner's retry decision needs the label before the next
        press); its pair estimates once the caller `keep`s the record (sent to the skin worker) and asks its
        `result`. Only a press that is kept is sent: a retried attempt costs the worker nothing."""
        press_id, n_sweeps, first, n = self._load()
        fsr_v = self._fsr_trace(first, n, press_id) if self.fsr_enabled else None
        marks = self._sample_marks(first)
        job = EstimateJob(press_id, n_sweeps, tuple(self.probe.segments), marks, values_only=True)
        record = DeferredRecord(
            first,
            n,
            self.sweep.rate_hz,
            marks,
            fsr_v,
            self.sweep.rate_hz / FSR_DECIMATION,
            job,
            worker,
        )
        self._press = None
        return record

    def _fsr_trace(self, first: int, n: int, press_id: int) -> np.ndarray:
        """The FSR channel alone, every FSR_DECIMATION-th sample (the features-only scene generates no V and I
        waveforms; the press detector needs the force's shape, not its 10 kHz detail)."""
        rate = self.sweep.rate_hz
        times = (first + np.arange(0, n, FSR_DECIMATION)) / rate
        n = times.size
        volts = self.daq.fsr.volts(self.probe.force_n(times))
        std_v = self.daq.noise.fsr_noise_v
        if std_v > 0:  # the stream (seed, press_id, STREAM_FSR), drawn one press ahead in a thread
            if self._fsr_noise is None or self._fsr_noise.std_v != std_v:
                self._fsr_noise = FsrNoiseAhead(self.seed, std_v)
            volts = volts + self._fsr_noise.take(press_id, n)
        return volts

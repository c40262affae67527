"""The real rig's recorder: the DAQ's finite acquisition runs in a thread while the printer moves;
marks are host times mapped onto the sample clock."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from neatskin.acquisition.daq.base import Daq
from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.record import PressRecord
from neatskin.acquisition.sequence import Sweep
from neatskin.errors import HardwareError


class ThreadedRecorder:
    """Real-rig recorder: the DAQ records in a thread while the printer moves."""

    def __init__(
        self,
        daq: Daq,
        sweep: Sweep,
        *,
        method: str,
        window: int,
        fsr_enabled: bool,
        keep_waveforms: bool,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.daq, self.sweep, self.clock = daq, sweep, clock
        self.method, self.window = method, window
        self.fsr_enabled, self.keep_waveforms = fsr_enabled, keep_waveforms

    def begin(self, press_id: int, n_sweeps: int) -> None:
        self._result: list = []
        self._marks: dict[str, float] = {}

        def work() -> None:
            try:
                self._result.append(self.daq.acquire(self.sweep, n_sweeps))
            except BaseException as exc:  # surfaced in end()
                self._result.append(exc)

        self._thread = threading.Thread(target=work, name=f"daq-press-{press_id}", daemon=True)
        self._t0 = self.clock()
        self._thread.start()

    def mark(self, name: str) -> None:
        self._marks[name] = self.clock()

    def end(self, timeout_s: float = 120.0) -> PressRecord:
        self._thread.join(timeout_s)
        if self._thread.is_alive() or not self._result:
            raise HardwareError(
                f"the DAQ did not finish its acquisition within {timeout_s:.0f} s "
                "(check the device and its sample clock)"
            )
        acq = self._result[0]
        if isinstance(acq, BaseException):
            raise HardwareError(f"DAQ acquisition failed: {acq}") from acq
        estimates = demodulate(acq, self.sweep, method=self.method, window=self.window)
        first = int(acq.sample_index[0])
        marks = {k: first + int(round((t - self._t0) * acq.rate_hz)) for k, t in self._marks.items()}
        waveforms = None
        if self.keep_waveforms:
            waveforms = {
                "voltage_v": acq.voltage_v.astype(np.float32),
                "current_a": acq.current_a.astype(np.float32),
                "fsr_v": acq.fsr_v.astype(np.float32),
            }
        return PressRecord(
            estimates,
            first,
            acq.n_samples,
            acq.rate_hz,
            marks,
            acq.fsr_v if self.fsr_enabled else None,
            waveforms,
            acq.rate_hz,
        )

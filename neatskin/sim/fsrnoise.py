"""The FSR channel's white noise of each dry-run press, drawn from its own stream (seed, press_id, STREAM_FSR) one
press ahead in a thread.

The draw is a pure function of (seed, press_id, samples), so drawing it early changes no value. numpy's generators
release the GIL while they fill an array, so the next press's draw runs on the other core while the main process
runs the current press's G-code: about 60 to 90 us a press (8,540 normals) off the campaign's critical path. A
press that was not foreseen (the first, a resumed campaign's gaps) is drawn inline; a retried press reuses its draw.
"""

from __future__ import annotations

import threading

import numpy as np

STREAM_FSR = 3  # the FSR noise's stream id (neatskin.sim.recorder re-exports it)
IDLE_EXIT_S = 2.0  # the drawing thread ends after this long without a draw to make (the next draw starts another)


def fsr_noise(seed: int, press_id: int, samples: int, std_v: float) -> np.ndarray:
    """std_v times `samples` standard normals of the stream (seed, press_id, STREAM_FSR): the press's FSR noise."""
    rng = np.random.default_rng([seed, press_id, STREAM_FSR])
    return rng.standard_normal(samples) * std_v


class FsrNoiseAhead:
    """`take(press_id, samples)` gives `fsr_noise(seed, press_id, samples, std_v)` and starts drawing the next
    press's (press_id + 1, the same length) in a daemon thread. At most one draw is kept ahead (68 kB for the paper
    press); the thread starts on the first foreseen draw, waits on a condition between draws and ends when none
    came for IDLE_EXIT_S (a campaign's end, a pause), so no recorder leaves a thread behind for long."""

    def __init__(self, seed: int, std_v: float) -> None:
        self.seed, self.std_v = seed, std_v
        self._lock = threading.Condition()
        self._want: tuple[int, int] | None = None  # the draw asked for and not yet made
        self._ready: dict[tuple[int, int], np.ndarray] = {}
        self._busy: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None

    def take(self, press_id: int, samples: int) -> np.ndarray:
        key = (press_id, samples)
        with self._lock:
            while self._busy == key:  # being drawn now: wait for it rather than draw it twice
                self._lock.wait()
            noise = self._ready.get(key)
            if noise is None and self._want == key:
                self._want = None
            # keep this press's draw (a retried press asks for it again) and any drawn ahead of it
            self._ready = {k: v for k, v in self._ready.items() if k[0] >= press_id}
        if noise is None:
            noise = fsr_noise(self.seed, press_id, samples, self.std_v)
            with self._lock:
                self._ready[key] = noise
        self._ahead((press_id + 1, samples))
        return noise

    def _ahead(self, key: tuple[int, int]) -> None:
        with self._lock:
            if key in self._ready or self._busy == key:
                return
            self._want = key
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="fsr-noise", daemon=True)
                self._thread.start()
            self._lock.notify_all()

    def _run(self) -> None:
        while True:
            with self._lock:
                while self._want is None:
                    if not self._lock.wait(IDLE_EXIT_S) and self._want is None:
                        self._thread = None  # under the lock: the next _ahead starts a new thread
                        return
                key, self._want, self._busy = self._want, None, self._want
            try:
                noise = fsr_noise(self.seed, key[0], key[1], self.std_v)  # the GIL is released while it fills
            except BaseException:  # take() draws it inline instead
                noise = None
            with self._lock:
                self._busy = None
                if noise is not None:
                    self._ready[key] = noise
                self._lock.notify_all()

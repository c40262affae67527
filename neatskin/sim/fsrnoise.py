"""The FSR channel's white noise of each dry-run press, drawn from its own stream (seed, press_id, STREAM_FSR) one
press ahead in a thread.

The draw is a pure function of (seed, press_id, samples), so drawing it early changes no value. numpy's generators
release the GIL while they fill an array, so the next press's draw runs on the other core while the main process
runs the current press's G-code: about 60 to 90 us a press (8,540 normals) off the campaign's critical path. A
press whose draw is not there when it is wanted (the first, a resumed campaign's gaps, a draw still running) is
drawn inline; a retried press reuses its draw.
"""

from __future__ import annotations

import queue
import threading

import numpy as np

STREAM_FSR = 3  # the FSR noise's stream id (neatskin.sim.recorder re-exports it)
IDLE_EXIT_S = 2.0  # the drawing thread ends after this long without a draw to make (the next draw starts another)
AHEAD_PRESSES = 8  # presses drawn per request: a wake-up of the thread costs the main process's GIL too


def fsr_noise(seed: int, press_id: int, samples: int, std_v: float) -> np.ndarray:
    """std_v times `samples` standard normals of the stream (seed, press_id, STREAM_FSR): the press's FSR noise."""
    rng = np.random.default_rng([seed, press_id, STREAM_FSR])
    return rng.standard_normal(samples) * std_v


class FsrNoiseAhead:
    """`take(press_id, samples)` gives `fsr_noise(seed, press_id, samples, std_v)`; when fewer than two of the next
    presses are asked for, it asks a daemon thread to draw the next AHEAD_PRESSES presses' (the same length).

    The main thread's side is a dict pop and, every few presses, a put on a C queue (no lock, no condition: a
    wake-up costs the main process's GIL, which is its bottleneck); whatever the thread has not drawn yet is drawn
    inline, so every interleaving gives the same values. At most AHEAD_PRESSES + 1 draws are kept (68 kB each for
    the paper press). The thread ends when no request came for IDLE_EXIT_S (a campaign's end, a pause), so no
    recorder leaves it behind for long."""

    def __init__(self, seed: int, std_v: float) -> None:
        self.seed, self.std_v = seed, std_v
        self._requests: queue.SimpleQueue[tuple[int, int, int] | None] = queue.SimpleQueue()
        self._drawn: dict[tuple[int, int], np.ndarray] = {}  # written by the thread, popped by take()
        self._last: tuple[tuple[int, int], np.ndarray] | None = None  # a retried press asks for the same draw
        self._thread: threading.Thread | None = None
        self._asked: tuple[int, int] = (-1, -1)  # (samples, the last press id asked for)

    def take(self, press_id: int, samples: int) -> np.ndarray:
        key = (press_id, samples)
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        noise = self._drawn.pop(key, None)
        if noise is None:
            noise = fsr_noise(self.seed, press_id, samples, self.std_v)
        for stale in list(self._drawn):  # drawn for a press that was skipped or already drawn inline
            if stale[0] <= press_id:
                self._drawn.pop(stale, None)
        self._last = (key, noise)
        asked_samples, until = self._asked
        same = asked_samples == samples
        if not (same and press_id + 2 <= until <= press_id + AHEAD_PRESSES):  # fewer than 2 presses ahead asked for
            first = until + 1 if same and press_id < until <= press_id + AHEAD_PRESSES else press_id + 1
            self._ahead(first, press_id + AHEAD_PRESSES, samples)
        return noise

    def _ahead(self, first: int, last: int, samples: int) -> None:
        thread = self._thread
        if thread is None or not thread.is_alive():
            thread = self._thread = threading.Thread(target=self._run, name="fsr-noise", daemon=True)
            thread.start()
        self._asked = (samples, last)
        self._requests.put((first, last, samples))

    def close(self, timeout_s: float = 1.0) -> None:
        """End the drawing thread now (the rig closes: no thread of the campaign outlives it); take() still works,
        drawing inline or starting a new thread."""
        thread = self._thread
        if thread is not None and thread.is_alive():
            self._requests.put(None)
            thread.join(timeout_s)  # at most one draw (~0.1 ms) to finish
        self._drawn.clear()
        self._asked = (-1, -1)

    def _run(self) -> None:
        while True:
            try:
                request = self._requests.get(timeout=IDLE_EXIT_S)
            except queue.Empty:
                return  # a request put meanwhile is drawn inline by take(), or by the next thread
            if request is None:  # close()
                return
            first, last, samples = request
            for press_id in range(first, last + 1):
                try:  # the GIL is free while it fills
                    self._drawn[(press_id, samples)] = fsr_noise(self.seed, press_id, samples, self.std_v)
                except Exception:  # take() draws it inline
                    break

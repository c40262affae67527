"""The FSR noise drawn one press ahead in a thread (neatskin.sim.fsrnoise) is the stream (seed, press_id,
STREAM_FSR) of each press, whatever order the presses come in (in order, retried, skipped as a resumed campaign
skips them), and its thread ends when idle."""

import time

import numpy as np

from neatskin.sim import fsrnoise
from neatskin.sim.fsrnoise import STREAM_FSR, FsrNoiseAhead, fsr_noise


def plain(seed, press_id, samples, std_v):
    return np.random.default_rng([seed, press_id, STREAM_FSR]).standard_normal(samples) * std_v


def test_every_press_gets_its_own_stream_in_any_order():
    ahead = FsrNoiseAhead(2019, 5e-3)
    order = [0, 1, 2, 2, 2, 3, 7, 8, 8, 20, 21, 5, 6]  # in order, retries, a resume's gaps, going back
    for press_id in order:
        got = ahead.take(press_id, 854)
        assert got.tobytes() == plain(2019, press_id, 854, 5e-3).tobytes(), press_id
        time.sleep(0.002 if press_id % 2 else 0.0)  # sometimes the next draw is ready, sometimes still drawing
    assert ahead.take(9, 100).tobytes() == plain(2019, 9, 100, 5e-3).tobytes()  # another length: drawn again
    assert fsr_noise(3, 4, 10, 1.0).tobytes() == plain(3, 4, 10, 1.0).tobytes()
    assert not np.array_equal(ahead.take(10, 854), ahead.take(11, 854))  # a negative control: streams differ


def test_the_drawing_thread_ends_when_idle_and_starts_again(monkeypatch):
    monkeypatch.setattr(fsrnoise, "IDLE_EXIT_S", 0.05)
    ahead = FsrNoiseAhead(7, 1.0)
    ahead.take(0, 50)
    thread = ahead._thread
    assert thread is not None
    thread.join(5.0)
    assert not thread.is_alive()  # nothing more was asked for
    ahead_ids = sorted(k[0] for k in ahead._drawn)
    assert ahead_ids == list(range(1, fsrnoise.AHEAD_PRESSES + 1))  # it drew the next presses before it ended
    for press_id in range(1, fsrnoise.AHEAD_PRESSES):
        assert ahead.take(press_id, 50).tobytes() == plain(7, press_id, 50, 1.0).tobytes()
    assert ahead._thread is not thread  # running low: a new thread asked for the next ones
    last = 3 * fsrnoise.AHEAD_PRESSES
    for press_id in range(fsrnoise.AHEAD_PRESSES, last + 1):
        assert ahead.take(press_id, 50).tobytes() == plain(7, press_id, 50, 1.0).tobytes()
    assert all(k[0] > last for k in ahead._drawn)  # nothing older is kept
    assert len(ahead._drawn) <= fsrnoise.AHEAD_PRESSES


def test_close_ends_the_thread_and_take_still_gives_the_stream():
    ahead = FsrNoiseAhead(11, 2.0)
    ahead.take(4, 30)
    thread = ahead._thread
    ahead.close()
    assert thread is not None and not thread.is_alive() and not ahead._drawn
    assert ahead.take(5, 30).tobytes() == plain(11, 5, 30, 2.0).tobytes()
    ahead.close()

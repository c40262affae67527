"""The skin worker's death before it was ready: a kill (a signal) is told apart from an exit by itself (what an
unguarded script's spawn re-import does), and only the second gets the `if __name__ == "__main__"` hint."""

import os
import signal
import time

import pytest

from neatskin.errors import HardwareError
from neatskin.sim.skinworker import EstimateJob, SkinWorker


def slow_to_start():
    time.sleep(60)  # the worker stays "not ready" until killed
    return lambda job: None


def exits_while_starting():
    os._exit(1)


def _error(worker: SkinWorker) -> str:
    ticket = worker.submit(EstimateJob(4, 1, ()))
    with pytest.raises(HardwareError) as info:
        worker.result(ticket, 4)
    return str(info.value)


def test_a_worker_killed_while_it_starts_is_not_blamed_on_the_script():
    worker = SkinWorker(slow_to_start, start_timeout_s=60).start()
    try:
        time.sleep(0.5)
        assert worker.pid is not None
        os.kill(worker.pid, signal.SIGKILL)
        text = _error(worker)
    finally:
        worker.close()
    assert "exit code -9" in text and "stopped by signal SIGKILL while it started" in text
    assert "__main__" not in text and "never" not in text and "before press 4's estimates" in text


def test_a_worker_that_exits_by_itself_before_ready_gets_the_main_guard_hint():
    worker = SkinWorker(exits_while_starting, start_timeout_s=60).start()
    try:
        text = _error(worker)
    finally:
        worker.close()
    assert "exit code 1" in text and "never became ready" in text and "__main__" in text

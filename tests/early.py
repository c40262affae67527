"""CPU-bound work a long test needs, started in a process of its own when its xdist worker starts, so that it runs
while the worker's first tests wait on the real firmware's clock (tests/suite_order.py starts those first on every
worker): the test then takes the result instead of computing it. The work is the
test's own function, run from the same code; only when it runs changes. A test that finds nothing started (no xdist,
or the test moved to another worker) computes it itself."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

#: node id -> (module, function) of the work its test needs; the function takes no argument.
WORK: dict[str, tuple[str, str]] = {
    "tests/test_skin_quasi3d.py::test_the_shipped_kernel_is_what_its_sources_give": (
        "test_skin_quasi3d",
        "kernel_again",
    ),
    "tests/test_skin_quasi3d.py::test_the_transfer_is_mesh_converged_on_the_host_side": (
        "test_skin_quasi3d",
        "fine_host_strains",
    ),
}

_started: dict[str, Future[Any]] = {}
_pool: ProcessPoolExecutor | None = None


def _run(module: str, function: str) -> Any:
    import importlib

    return getattr(importlib.import_module(module), function)()


def start(nodeid: str) -> None:
    """Start the work of the test `nodeid` in a process of its own (spawned: this worker has threads)."""
    global _pool
    if nodeid in _started or nodeid not in WORK:
        return
    if _pool is None:
        _pool = ProcessPoolExecutor(max_workers=len(WORK), mp_context=multiprocessing.get_context("spawn"))
    _started[nodeid] = _pool.submit(_run, *WORK[nodeid])


def result(nodeid: str, compute: Callable[[], Any]) -> Any:
    """The work started for `nodeid`, once done; else compute() here."""
    future = _started.pop(nodeid, None)
    return compute() if future is None else future.result()


def stop() -> None:
    """End what was started and is no longer wanted (its test ran elsewhere or not at all): the session does not wait
    for it."""
    global _pool
    if _pool is None:
        return
    for future in _started.values():
        future.cancel()
    for process in list(getattr(_pool, "_processes", {}).values()):  # Python 3.11 has no public way to end them
        process.terminate()
    _pool.shutdown(wait=True, cancel_futures=True)
    _pool = None
    _started.clear()

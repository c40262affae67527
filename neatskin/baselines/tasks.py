"""Running the report's independent tasks (fits, the physics inversion) in processes: costliest first, by key.

A `Task` is a pure function call with a key and an estimated cost. `run_tasks` runs a list of
them and returns their outputs by key, so the order tasks run in, and the process each runs in,
never changes a result:

- in parallel, this process is one of the lanes: it takes the cheapest tasks while worker processes
  (one fewer than the lanes) take the costliest first, so the end of the run is not one long task with
  every other core idle (the costs are estimates, used for nothing but this order). This process has
  already imported what a fit needs (scikit-learn, scipy, numpy: about 140 MB a process, hardly shared
  between spawned processes), so one worker fewer is that much less memory at the same parallelism;
- every lane's BLAS and OpenMP run on the same threads a joblib worker gets (cores // lanes, mostly 1),
  so a task gives the same numbers in either lane;
- the workers end when the tasks do, before the caller goes on (no idle worker holds memory);
- results are taken as they finish (the progress bar moves with the work done);
- `meanwhile` runs in this process before its share of the tasks (e.g. a figure that needs no fit);
- first this process gives back the memory it has freed but its allocators keep (`release_freed_memory`).

With n_jobs = 1 and no backend the tasks run here, in the given order. A joblib `backend` (e.g. Dask, or
"threading") runs every task through joblib instead, costliest first, with `meanwhile` overlapping them.
"""

from __future__ import annotations

import collections
import ctypes
import os
import sys
import threading
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

# the thread-count variables joblib sets in its workers (joblib's _parallel_backends.MAX_NUM_THREADS_VARS)
THREAD_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMBA_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


@dataclass(frozen=True)
class Task:
    """One independent call: `func(*args)`, found again by `key`; `cost_s` only orders the tasks."""

    key: Hashable
    cost_s: float
    func: Callable[..., Any]
    args: tuple


def _keyed(key: Hashable, func: Callable[..., Any], args: tuple) -> tuple[Hashable, Any]:
    return key, func(*args)


def costliest_first(tasks: Sequence[Task]) -> list[Task]:
    """The tasks by decreasing estimated cost; equal costs keep their given order."""
    return sorted(tasks, key=lambda task: -task.cost_s)


def lanes_for(n_jobs: int) -> int:
    """How many tasks run at once for n_jobs (-1: every core, -2: all but one, as joblib counts)."""
    cores = os.cpu_count() or 1
    return max(1, cores + 1 + n_jobs if n_jobs < 0 else n_jobs)


def run_tasks(
    tasks: Sequence[Task],
    n_jobs: int = 1,
    backend: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> dict[Hashable, Any]:
    """Every task's output by key. n_jobs: lanes (1 = here, -1 = every core; this process is one of them);
    backend: joblib's, to run every task through it instead.

    progress: optional callable(done_tasks, total_tasks). meanwhile: optional work for this
    process, run before it takes tasks (once the workers have theirs).
    """
    keys = [task.key for task in tasks]
    if len(set(keys)) != len(keys):
        raise ValueError("task keys must be unique")
    release_freed_memory()
    if backend is not None:
        return _run_joblib(tasks, n_jobs, backend, progress, meanwhile)
    lanes = min(lanes_for(n_jobs), max(len(tasks), 1))
    if lanes == 1:
        outputs: dict[Hashable, Any] = {}
        if meanwhile is not None:
            meanwhile()
        for task in tasks:
            outputs[task.key] = task.func(*task.args)
            if progress is not None:
                progress(len(outputs), len(tasks))
        return outputs
    return _Lanes(tasks, lanes, progress).run(meanwhile)


def release_freed_memory() -> None:
    """Give the operating system back what this process has freed but its allocators keep cached: pyarrow's
    memory pool (mimalloc or jemalloc) and glibc's heap (malloc_trim). A campaign's threads (G-code driver, wire
    log, physical limit) each allocate in their own glibc arena, which keeps its freed pages; measured before
    the paper dry run's report: 16 MB back from pyarrow's pool and 26 MB from glibc. Freeing changes no value."""
    arrow = sys.modules.get("pyarrow")
    if arrow is not None:
        arrow.default_memory_pool().release_unused()
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # not glibc (macOS, musl): nothing to trim
        return
    trim(0)


def _threads_per_lane(lanes: int) -> int:
    return max((os.cpu_count() or 1) // lanes, 1)


def _start_worker(threads: int, parent_pid: int) -> None:
    """A worker's initializer: BLAS and OpenMP on `threads` threads (as joblib sets them, the user's own
    setting kept), Ctrl-C left to the main process, which ends the workers, and the worker's end when that
    process is killed outright (it would otherwise wait forever to send its result: neatskin.orphans)."""
    import signal

    from neatskin.orphans import end_with_parent

    end_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for var in THREAD_VARS:
        os.environ.setdefault(var, str(threads))
    from threadpoolctl import threadpool_limits

    threadpool_limits(threads)  # libraries the worker had loaded before this ran (none, usually)


class _Lanes:
    """`lanes - 1` spawned worker processes and this process, sharing one queue costliest first: each worker's
    feeder thread takes from the dear end, this process from the cheap end. A task's error ends the run."""

    def __init__(self, tasks: Sequence[Task], lanes: int, progress: Callable[[int, int], None] | None) -> None:
        self.queue = collections.deque(costliest_first(tasks))
        self.total, self.lanes, self.progress = len(tasks), lanes, progress
        self.lock = threading.Lock()
        self.outputs: dict[Hashable, Any] = {}
        self.error: BaseException | None = None

    def _take(self, dear: bool) -> Task | None:
        with self.lock:
            if self.error is not None or not self.queue:
                return None
            return self.queue.popleft() if dear else self.queue.pop()

    def _done(self, task: Task, output: Any) -> None:
        with self.lock:
            self.outputs[task.key] = output
            done = len(self.outputs)
        if self.progress is not None:
            self.progress(done, self.total)

    def _fail(self, error: BaseException) -> None:
        with self.lock:
            if self.error is None:
                self.error = error

    def _feed(self, pool: Any) -> None:
        while (task := self._take(dear=True)) is not None:
            try:
                output = pool.submit(task.func, *task.args).result()
            except BaseException as exc:  # raised again in the caller's thread
                self._fail(exc)
                return
            self._done(task, output)

    def run(self, meanwhile: Callable[[], None] | None) -> dict[Hashable, Any]:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from threadpoolctl import threadpool_limits

        threads = _threads_per_lane(self.lanes)
        # spawn, never fork: this process has threads (a campaign's, the feeders)
        pool = ProcessPoolExecutor(
            self.lanes - 1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(threads, os.getpid()),
        )
        feeders = [threading.Thread(target=self._feed, args=(pool,), daemon=True) for _ in range(self.lanes - 1)]
        for feeder in feeders:
            feeder.start()
        finished = False
        try:
            if meanwhile is not None:
                meanwhile()
            with threadpool_limits(threads):
                while (task := self._take(dear=False)) is not None:
                    self._done(task, task.func(*task.args))
            for feeder in feeders:
                feeder.join()
            finished = True
        except BaseException as exc:
            self._fail(exc)
            raise
        finally:
            _end_pool(pool, wait=finished)
        if self.error is not None:
            raise self.error
        return self.outputs


def _end_pool(pool: Any, wait: bool) -> None:
    """Shut the workers down; after an error or Ctrl-C, end them at once rather than wait for a long task."""
    # Python 3.14 has pool.terminate_workers(); before it the processes are only in this private mapping, which
    # shutdown() clears
    processes = [] if wait else list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    pool.shutdown(wait=wait, cancel_futures=True)


def _run_joblib(
    tasks: Sequence[Task],
    n_jobs: int,
    backend: str,
    progress: Callable[[int, int], None] | None,
    meanwhile: Callable[[], None] | None,
) -> dict[Hashable, Any]:
    from joblib import Parallel, delayed, parallel_backend

    outputs: dict[Hashable, Any] = {}
    calls = [delayed(_keyed)(task.key, task.func, task.args) for task in costliest_first(tasks)]
    with parallel_backend(backend, n_jobs=n_jobs):
        # joblib dispatches the first tasks when the Parallel is called, so `meanwhile` overlaps them
        stream = Parallel(return_as="generator_unordered")(calls)
        if meanwhile is not None:
            meanwhile()
        for key, out in stream:
            outputs[key] = out
            if progress is not None:
                progress(len(outputs), len(tasks))
    return outputs

"""Running the report's independent tasks (fits, the physics inversion) in processes: costliest first, by key.

A `Task` is a pure function call with a key and an estimated cost. `run_tasks` runs a list of
them through joblib (processes by default; its backend can be Dask) and returns their outputs
by key, so the order tasks run in never changes a result:

- in processes the costliest tasks start first, so the end of the run is not one long task
  with every other core idle (the costs are estimates, used for nothing but this order);
- results are taken as they finish (the progress bar moves with the work done);
- arrays above `SHARED_ARRAY_BYTES` go to the workers once as a shared memory map, not pickled
  into every task;
- `meanwhile` runs in this process while the workers compute (e.g. a figure that needs no fit).

With n_jobs = 1 and no backend the tasks run here, in the given order.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

SHARED_ARRAY_BYTES = "100K"  # joblib's max_nbytes: the features of a 2,800-press dataset are ~0.6 MB


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


def run_tasks(
    tasks: Sequence[Task],
    n_jobs: int = 1,
    backend: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> dict[Hashable, Any]:
    """Every task's output by key. n_jobs: processes (1 = here, -1 = every core); backend: joblib's.

    progress: optional callable(done_tasks, total_tasks). meanwhile: optional work for this
    process, run once the tasks are dispatched (first, when they run here).
    """
    keys = [task.key for task in tasks]
    if len(set(keys)) != len(keys):
        raise ValueError("task keys must be unique")
    outputs: dict[Hashable, Any] = {}
    if n_jobs == 1 and backend is None:
        if meanwhile is not None:
            meanwhile()
        for task in tasks:
            outputs[task.key] = task.func(*task.args)
            if progress is not None:
                progress(len(outputs), len(tasks))
        return outputs
    from joblib import Parallel, delayed, parallel_backend

    calls = [delayed(_keyed)(task.key, task.func, task.args) for task in costliest_first(tasks)]
    name = backend or "loky"
    shared = {"max_nbytes": SHARED_ARRAY_BYTES} if name == "loky" else {}
    with parallel_backend(name, n_jobs=n_jobs):
        # joblib dispatches the first tasks when the Parallel is called, so `meanwhile` overlaps them
        stream = Parallel(return_as="generator_unordered", **shared)(calls)
        if meanwhile is not None:
            meanwhile()
        for key, out in stream:
            outputs[key] = out
            if progress is not None:
                progress(len(outputs), len(tasks))
    return outputs

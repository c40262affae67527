"""Worker processes that end with their parent: a watch for the processes a run starts (a fit worker, a queue's
manager), so a run killed outright (SIGKILL, a crash, the machine's OOM killer) leaves nothing behind.

A process a run spawns outlives a parent killed outright: a fit worker blocked sending its result into a pipe it
holds both ends of, a manager serving a queue, wait forever. Passed as their initializer, `end_with_parent` starts
a daemon thread that ends the process once its parent is gone (its parent pid changes: it was adopted).
"""

from __future__ import annotations

import os
import threading
import time

WATCH_PERIOD_S = 0.5  # how often the parent is looked for: a process outlives its parent by at most this


def end_with_parent(parent_pid: int) -> None:
    """In a child process: end it (os._exit(0), nothing of the dead run left to save) once `parent_pid` is no
    longer its parent. Call it first thing in the child, with the parent's os.getpid() taken in the parent."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(WATCH_PERIOD_S)
        os._exit(0)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def watched_parallel(n_jobs: int, **kwargs):
    """A joblib `Parallel` on its loky process pool whose workers end with this process (`end_with_parent` as
    their initializer). loky's idle workers otherwise wait out their 300 s idle timeout after a run killed outright,
    and a busy one runs its task (a design candidate: minutes) to the end for nobody. kwargs go to `Parallel`."""
    from joblib import Parallel

    return Parallel(n_jobs=n_jobs, backend="loky", initializer=end_with_parent, initargs=(os.getpid(),), **kwargs)

"""Running a study: candidates evaluated in this process, in parallel with joblib, or on a Dask distributed cluster;
each result made durable as soon as it arrives (one small parquet per candidate, written atomically by this
process), so a re-run of a killed study skips what is done and never holds a candidate twice.

The scheduler only moves `evaluate_candidate(study, candidate)` calls around; the numbers are the same whichever
runs them. `dask` and `distributed` (the optional extra `neatskin-rig[cluster]`) are imported only for
scheduler="dask".
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator
from pathlib import Path

import pandas as pd

from neatskin.datasets.durable import remove_temp_files, write_bytes_durably, write_durably
from neatskin.design.candidates import Candidate, expand
from neatskin.design.evaluate import CandidateResult, evaluate_candidate
from neatskin.design.report import MAPS, write_candidate, write_report
from neatskin.design.study import FINGERPRINT, PARTS, Study, study_fingerprint
from neatskin.errors import ConfigError

log = logging.getLogger(__name__)

SCHEDULERS = ("local", "dask")

Progress = Callable[[int, int], None]
Tick = Callable[[float], None]


def default_jobs() -> int:
    """The cores this process may run on (its CPU affinity, else os.cpu_count())."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def done_ids(out_dir: Path) -> set[str]:
    parts = out_dir / PARTS
    return {p.stem for p in parts.glob("*.parquet")} if parts.is_dir() else set()


def prepare_out_dir(study: Study, out_dir: Path) -> None:
    """Create the folder; refuse one that holds another study's results (a resume must be the same study)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / PARTS).mkdir(exist_ok=True)
    (out_dir / MAPS).mkdir(exist_ok=True)
    for folder in (out_dir, out_dir / PARTS, out_dir / MAPS):
        remove_temp_files(folder)
    fingerprint = study_fingerprint(study)
    path = out_dir / FINGERPRINT
    if path.exists():
        previous = json.loads(path.read_text(encoding="utf-8"))
        if previous != fingerprint:
            changed = sorted(k for k in fingerprint if previous.get(k) != fingerprint[k])
            raise ConfigError(
                f"{out_dir} holds results of a different study (changed: {', '.join(changed) or 'format'})",
                file=study.source,
                field=changed[0] if changed else None,
                fix="give another --out folder, or delete that one to start over",
            )
        return
    write_bytes_durably(path, json.dumps(fingerprint, indent=1, sort_keys=True).encode())


def run_study(
    study: Study,
    out_dir: str | Path,
    *,
    jobs: int | None = None,
    scheduler: str = "local",
    address: str | None = None,
    progress: Progress | None = None,
    tick: Tick | None = None,
    on_result: Callable[[CandidateResult], None] | None = None,
    pngs: bool = True,
    connect_timeout_s: float = 20.0,
) -> pd.DataFrame:
    """Evaluate every candidate not yet done in out_dir, durably, then write candidates.parquet and report.md.

    progress(done, total) is told after each candidate (done counts the ones a previous run finished); tick(share)
    within a candidate, per tile of presses, learned seed or inversion step (local and joblib runs; a Dask run
    ticks per candidate only); on_result(result) after each is durable. jobs: local worker processes, default
    the cores this process may use. Returns the candidates table (one row per candidate, study order).
    """
    if scheduler not in SCHEDULERS:
        raise ConfigError(f"unknown scheduler {scheduler!r}", field="--scheduler", fix="use 'local' or 'dask'")
    if scheduler == "dask" and not address:
        raise ConfigError(
            "--scheduler dask needs the cluster's address",
            field="--address",
            fix="pass --address tcp://HOST:PORT (the scheduler of a running Dask cluster)",
        )
    jobs = default_jobs() if jobs is None else jobs
    if jobs < 1:
        raise ConfigError(f"--jobs must be >= 1, got {jobs}", field="--jobs", fix="give 1 or more")
    out = Path(out_dir)
    prepare_out_dir(study, out)
    candidates = expand(study)
    if not candidates:
        raise ConfigError(
            "the study has no feasible candidate",
            file=study.source,
            field="electrodes",
            fix="check the counts and strategies against the grid sizes",
        )
    finished = done_ids(out)
    todo = [c for c in candidates if c.candidate_id not in finished]
    done = len(candidates) - len(todo)
    log.info("study %s: %d candidates, %d already done", study.name, len(candidates), done)
    if progress is not None:
        progress(done, len(candidates))
    for result in _results(study, todo, jobs, scheduler, address, connect_timeout_s, tick):
        write_candidate(out, result, png=pngs)
        done += 1
        if on_result is not None:
            on_result(result)
        if progress is not None:
            progress(done, len(candidates))
    frame = collect(out, candidates)
    write_report(out, study, frame)
    return frame


def collect(out_dir: Path, candidates: list[Candidate]) -> pd.DataFrame:
    """The candidates table from the per-candidate parts, in study order."""
    rows = [pd.read_parquet(out_dir / PARTS / f"{c.candidate_id}.parquet") for c in candidates]
    frame = pd.concat(rows, ignore_index=True)
    write_durably(out_dir / "candidates.parquet", lambda handle: frame.to_parquet(handle, index=False))
    return frame


def _results(
    study: Study,
    todo: list[Candidate],
    jobs: int,
    scheduler: str,
    address: str | None,
    timeout_s: float,
    tick: Tick | None = None,
) -> Iterator[CandidateResult]:
    if not todo:
        return
    if scheduler == "dask":
        yield from _dask_results(study, todo, address or "", timeout_s)
    elif jobs == 1 or len(todo) == 1:
        for candidate in todo:
            yield evaluate_candidate(study, candidate, tick)
    else:
        yield from _joblib_results(study, todo, min(jobs, len(todo)), tick)


def _joblib_results(study: Study, todo: list[Candidate], jobs: int, tick: Tick | None) -> Iterator[CandidateResult]:
    """Candidates in joblib worker processes; their ticks travel back through a manager queue, drained here by
    a thread (the workers' shares only move a progress bar: the results are the same without it)."""
    import threading

    from joblib import delayed

    from neatskin.orphans import watched_parallel

    parallel = watched_parallel(jobs, return_as="generator_unordered")
    if tick is None:
        yield from parallel(delayed(evaluate_candidate)(study, c) for c in todo)
        return
    import os
    from multiprocessing.managers import SyncManager

    from neatskin.orphans import end_with_parent

    manager = SyncManager()
    manager.start(end_with_parent, (os.getpid(),))  # a killed study's manager would serve forever
    with manager:
        queue = manager.Queue()

        def drain() -> None:
            while (share := queue.get()) is not None:
                tick(share)

        thread = threading.Thread(target=drain, name="design-ticks", daemon=True)
        thread.start()
        try:
            yield from parallel(delayed(evaluate_candidate)(study, c, queue.put) for c in todo)
        finally:
            queue.put(None)
            thread.join(timeout=10.0)


def _dask_results(study: Study, todo: list[Candidate], address: str, timeout_s: float) -> Iterator[CandidateResult]:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise ConfigError(
            "--scheduler dask needs dask and distributed",
            field="--scheduler",
            fix="pip install 'neatskin-rig[cluster]'",
        ) from exc
    try:
        client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except OSError as exc:
        raise ConfigError(
            f"cannot reach the Dask scheduler at {address}: {exc}",
            field="--address",
            fix="start the cluster (dask scheduler / dask worker) or correct the address",
        ) from exc
    try:
        # the study is small: it travels with each task, so a restarted worker needs nothing scattered
        futures = [
            client.submit(evaluate_candidate, study, c, key=f"design-{c.candidate_id}", pure=False, retries=2)
            for c in todo
        ]
        for future in as_completed(futures, loop=client.loop):
            yield future.result()
            future.release()
    finally:
        client.close()

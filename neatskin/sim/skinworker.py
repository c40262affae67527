"""The dry run's second core: one worker process that computes each kept press's pair estimates (the simulated
skin and DAQ), in press order, while the main process runs the next presses' G-code, FSR label and writing.

The main process holds one GIL for the driver, the simulated printer and the runner; the skin's per-depth
evaluation is arithmetic that threads cannot share. So the features scene's estimates (`features_estimates`,
the same function the inline recorder calls, on the same random stream keyed by (seed, press_id)) run in a
`multiprocessing` spawn process (never fork: the main process has threads), fed one `EstimateJob` per press
(the press's moves on its own clock) and answering in the order it was fed. This module carries the jobs and
answers and knows no skin: the estimator the worker builds is `sim.pressestimator.PressEstimator`. The FSR trace
is not deferred: the runner's retry decision needs the label before the next press.

The worker ignores SIGINT, SIGTERM and SIGHUP (they reach the whole process group; the main process stops cleanly
and then closes the worker), and it exits by itself when the main process goes away (EOF on its pipe). Every wait on it
has a deadline; its failure, death or silence is one HardwareError naming the press.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import importlib
import logging
import multiprocessing
import os
import signal
import threading
import time
import weakref
from collections.abc import Iterator
from multiprocessing.connection import Connection, wait
from typing import Any, Protocol

from neatskin import stopsignals
from neatskin.acquisition.estimates import PairEstimates
from neatskin.acquisition.pressvalues import PressValues
from neatskin.errors import ConfigError, HardwareError
from neatskin.sim.deferred import Estimated, EstimateJob

log = logging.getLogger(__name__)

START_TIMEOUT_S = 120.0  # the worker's imports and skin model, on a loaded machine
PRESS_TIMEOUT_S = 60.0  # one press's estimates take milliseconds; this is a hang, not a slow press
CLOSE_TIMEOUT_S = 5.0
CONTEXT = "spawn"
RESUME_HINT = "the presses before it are written, `neatskin campaign resume` presses the rest"


class Estimator(Protocol):
    def __call__(self, job: EstimateJob) -> PairEstimates | Estimated | PressValues: ...


class EstimatorFactory(Protocol):
    """Builds the worker's Estimator in the worker; picklable (a module-level function, or a partial of one)."""

    def __call__(self) -> Estimator: ...


class SkinWorker:
    """One worker process computing EstimateJobs in the order they are submitted; results come back in that order.

    `start()` launches it (its imports and model build overlap whatever the caller does next); `close()` ends it.
    """

    def __init__(
        self,
        factory: EstimatorFactory,
        *,
        start_timeout_s: float = START_TIMEOUT_S,
        press_timeout_s: float = PRESS_TIMEOUT_S,
        context: str = CONTEXT,
    ) -> None:
        if context == "fork":
            raise ValueError("the skin worker must not fork a process that has threads: use spawn or forkserver")
        self.factory = factory
        self.start_timeout_s, self.press_timeout_s, self.context = start_timeout_s, press_timeout_s, context
        self._process: Any = None
        self._conn: Connection | None = None
        self._ready = False
        self._received = 0  # answers taken: the next ticket due
        self._pending: collections.deque[int] = collections.deque()  # press ids submitted, not yet answered
        self._broken: HardwareError | None = None  # once failed, every later call raises this at once
        self.wait_s = 0.0  # how long the caller waited for answers (the worker behind), logged at close

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def start(self) -> SkinWorker:
        """Start the worker's process (or adopt the one `prestart` launched) and send it the factory."""
        adopted = _take_prestarted(self.context)
        process, ours = adopted if adopted is not None else _launch(self.context)
        self._process, self._conn = process, ours
        _LIVE.add(self)
        log.debug("skin worker %s, pid %s", "adopted" if adopted else "started", process.pid)
        # the factory (the protocol, ~70 kB) goes over our pipe, not in spawn's start-up data: spawn writes that
        # to a pipe the child reads only after importing the main module, so a payload over the pipe's 64 kB
        # would hold start() until then (and forever if the child dies first)
        try:
            ours.send(self.factory)
        except OSError:
            self._fail(self._died(0))
        return self

    def submit(self, job: EstimateJob) -> int:
        """Queue a press; returns its ticket (the order it will come back in)."""
        conn = self._connection()
        with contextlib.suppress(OSError):  # the worker is gone: result() still reads the answers it sent, then
            conn.send(job)  # names the first press it owes
        self._pending.append(job.press_id)
        return self._received + len(self._pending) - 1

    def result(self, ticket: int, press_id: int) -> PairEstimates | Estimated | PressValues:
        """The estimates of the press with this ticket, the next one due."""
        if self._broken is not None:
            raise self._broken
        if ticket != self._received:
            raise RuntimeError(f"press {press_id}: the skin worker answers in order; ticket {self._received} is next")
        while True:
            message = self._receive(press_id)
            if message[0] == "ready":
                self._ready = True
                continue
            if message[0] == "ok" and message[1] == press_id:
                self._received += 1
                self._pending.popleft()
                return message[2]
            if message[0] == "error":
                what = "could not start" if message[1] is None else f"failed on press {message[1]}"
                raise self._fail(HardwareError(f"the dry run's skin worker {what}: {message[2]}; {RESUME_HINT}"))
            raise RuntimeError(f"press {press_id}: unexpected answer from the skin worker: {message[:2]!r}")

    def close(self) -> None:
        """Ask the worker to end, and end it if it does not within CLOSE_TIMEOUT_S."""
        process, conn = self._process, self._conn
        self._process = self._conn = None
        if process is not None:
            log.debug("skin worker: %d presses, the caller waited %.2f s for them", self._received, self.wait_s)
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.send(None)
        if process is not None:
            process.join(0.0 if self._broken is not None else CLOSE_TIMEOUT_S)  # a hung worker is not waited for
            if process.is_alive():
                if self._broken is None:
                    log.warning("the skin worker (pid %s) did not end; terminating it", process.pid)
                process.kill()  # it ignores SIGTERM (a stop signal reaches the whole group) and holds no files
                process.join(CLOSE_TIMEOUT_S)
        if conn is not None:
            conn.close()

    def _connection(self) -> Connection:
        if self._broken is not None:
            raise self._broken
        if self._conn is None:
            raise RuntimeError("the skin worker is not running: start() it first")
        return self._conn

    def _receive(self, press_id: int) -> tuple:
        conn = self._connection()
        if conn.poll():
            return self._recv(conn, press_id)
        started = time.perf_counter()
        try:
            return self._wait_receive(conn, press_id)
        finally:
            self.wait_s += time.perf_counter() - started

    def _recv(self, conn: Connection, press_id: int) -> tuple:
        try:
            return conn.recv()
        except (EOFError, OSError):
            raise self._fail(self._died(press_id)) from None

    def _wait_receive(self, conn: Connection, press_id: int) -> tuple:
        timeout = self.press_timeout_s if self._ready else self.start_timeout_s
        deadline = time.monotonic() + timeout
        while True:
            if conn.poll():  # data, or EOF when the worker is gone (its answers already sent still come first)
                return self._recv(conn, press_id)
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise self._fail(
                    HardwareError(
                        f"the dry run's skin worker (pid {self.pid}) gave no estimates for press {press_id} within "
                        f"{timeout:.0f} s; {RESUME_HINT}"
                    )
                )
            ready = wait([conn, self._process.sentinel], remaining)
            if ready and conn not in ready and not conn.poll():
                raise self._fail(self._died(press_id))

    def _fail(self, error: HardwareError) -> HardwareError:
        self._broken = error
        return error

    def _died(self, press_id: int) -> HardwareError:
        """The error for a worker that is gone, naming the first press it owes (else `press_id`)."""
        press_id = self._pending[0] if self._pending else press_id
        process = self._process
        if process is not None:
            process.join(0.5)
        code = None if process is None else process.exitcode
        if self._ready:
            hint = ""
        elif code is not None and code < 0:  # a signal ended it while it started (a kill, the OOM killer)
            hint = f" (it was stopped by signal {_signal_name(-code)} while it started; the campaign's code is fine)"
        else:  # it exited by itself before it was ready: what a spawn re-importing an unguarded script does
            hint = (
                " (it never became ready: a Python script that runs a campaign must guard its top level with "
                '`if __name__ == "__main__":`, which multiprocessing\'s spawn re-imports, or set '
                "NEATSKIN_SKIN_WORKER=off)"
            )
        return HardwareError(
            f"the dry run's skin worker (pid {self.pid}) ended (exit code {code}) before press {press_id}'s "
            f"estimates{hint}; {RESUME_HINT}"
        )


def _launch(context: str, preload: tuple[str, ...] = ()) -> tuple[Any, Connection]:
    """A worker process waiting for its factory, and our end of its pipe; it imports `preload` meanwhile."""
    ctx: Any = multiprocessing.get_context(context)  # spawn or forkserver (typeshed: BaseContext)
    ours, theirs = ctx.Pipe(duplex=True)
    process = ctx.Process(target=serve, args=(theirs, preload), name="neatskin-skin-worker", daemon=True)
    with _stop_signals_ignored():  # the child starts with them ignored, before its first line could catch one
        process.start()
    theirs.close()  # ours is then the pipe's only other end: the worker sees EOF when this process dies
    return process, ours


# at most one worker launched ahead of its factory (`prestart`): (context, process, our end of its pipe)
_PRESTARTED: list[tuple[str, Any, Connection]] = []
_LIVE: weakref.WeakSet[SkinWorker] = weakref.WeakSet()  # workers started and not closed yet


def _close_at_exit() -> None:
    """At interpreter exit, end every worker this process still holds (closing the pipe, then kill()). The
    workers ignore SIGTERM, so multiprocessing's own exit hook (terminate, then join) would wait for ever on one
    left open (a campaign refused after the prestart); registered after multiprocessing's, this runs first."""
    discard_prestarted()
    for worker in list(_LIVE):
        worker.close()


atexit.register(_close_at_exit)


SKIN_WORKER_ENV = "NEATSKIN_SKIN_WORKER"  # on | off: force the dry run's skin worker either way (benchmarks)


def forced_by_env() -> bool | None:
    """SKIN_WORKER_ENV: on True, off False, unset None (the dry rig's own rule decides); anything else is one
    ConfigError naming the variable."""
    forced = os.environ.get(SKIN_WORKER_ENV, "").strip().lower()
    if forced in ("on", "off"):
        return forced == "on"
    if forced:
        raise ConfigError(
            f"{SKIN_WORKER_ENV}={forced!r} is not a skin worker setting",
            field=SKIN_WORKER_ENV,
            fix="set it to on or off, or unset it for the default",
        )
    return None


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the OS tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def prestart(preload: tuple[str, ...] = (), context: str = CONTEXT) -> None:
    """Launch a worker process now, before the campaign that needs it exists: its interpreter start, imports and
    `preload` modules run while this process loads the protocol, plans and opens the campaign folder; the next
    `SkinWorker.start()` adopts it. One not adopted ends at `discard_prestarted()` or, at the latest, when this
    process ends (EOF on its pipe)."""
    if not _PRESTARTED:
        _PRESTARTED.append((context, *_launch(context, preload)))


def discard_prestarted() -> None:
    """End a prestarted worker nobody adopted (a campaign that computes its estimates inline)."""
    while _PRESTARTED:
        _, process, conn = _PRESTARTED.pop()
        _end_prestarted(process, conn)


def _end_prestarted(process, conn: Connection) -> None:
    conn.close()  # EOF: the worker returns
    process.join(CLOSE_TIMEOUT_S)
    if process.is_alive():
        process.kill()
        process.join(CLOSE_TIMEOUT_S)


def _take_prestarted(context: str) -> tuple[Any, Connection] | None:
    while _PRESTARTED:
        kind, process, conn = _PRESTARTED.pop()
        if kind == context and process.is_alive():
            return process, conn
        _end_prestarted(process, conn)
    return None


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return str(number)


@contextlib.contextmanager
def _stop_signals_ignored() -> Iterator[None]:
    """While a worker starts: Ctrl-C, SIGTERM and SIGHUP ignored here, so the child inherits them ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may touch signal handlers; the worker ignores them from its first line
        return
    previous = {signum: signal.getsignal(signum) for signum in stopsignals.STOP_SIGNALS}
    for signum, handler in previous.items():
        if handler is not None:  # None: a handler not set from Python, left alone
            signal.signal(signum, signal.SIG_IGN)  # SIG_IGN, not a Python handler: only SIG_IGN survives exec
    try:
        yield
    finally:
        for signum, handler in previous.items():
            if handler is not None:
                signal.signal(signum, handler)


def _ignore_stop_signals() -> None:
    """Ctrl-C, SIGTERM (systemctl stop) and SIGHUP (a lost terminal) reach the whole group: the main process
    stops cleanly and then closes the worker; the worker ends by itself on EOF if the main process is gone."""
    for signum in stopsignals.STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def serve(conn: Connection, preload: tuple[str, ...] = ()) -> None:
    """The worker's loop: import `preload` (a prestarted worker waits for its factory), receive the factory and
    build the estimator, say ready, answer each job in order; end on None or EOF."""
    _ignore_stop_signals()
    for name in preload:
        try:
            importlib.import_module(name)
        except ImportError as exc:  # the factory's own import then names the problem
            log.debug("skin worker: cannot preload %s: %s", name, exc)
    try:
        factory = conn.recv()
    except (EOFError, OSError):
        return
    try:
        estimate = factory()
    except Exception as exc:
        _send(conn, ("error", None, f"{type(exc).__name__}: {exc}"))
        return
    if not _send(conn, ("ready",)):
        return
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):  # the main process closed its end or died: nobody wants the rest
            return
        if job is None:
            return
        try:
            message: tuple = ("ok", job.press_id, estimate(job))
        except Exception as exc:
            message = ("error", job.press_id, f"{type(exc).__name__}: {exc}")
        if not _send(conn, message):
            return


def _send(conn: Connection, message: tuple) -> bool:
    try:
        conn.send(message)
    except OSError:
        return False
    return True

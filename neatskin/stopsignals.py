"""The signals that stop a command as Ctrl-C does: SIGINT, SIGTERM (systemctl stop, docker stop, timeout, kill)
and SIGHUP (a dropped SSH session, a closed terminal).

Python turns only SIGINT into KeyboardInterrupt; SIGTERM and SIGHUP would end the process where it stands, with
the probe pressed into the skin and the campaign's manifest still "running". `handled(handler)` runs one handler
for all three (the press loop's stop request), `as_ctrl_c()` makes SIGTERM and SIGHUP do whatever SIGINT does when
they arrive (a command's whole run), so each command has one stop path, tested once per signal.

A SIGHUP from a lost terminal leaves that terminal's output dead (a write fails with EIO): the standard streams
that were on a terminal are pointed at /dev/null first, so the lift and park that follow never fail on a print.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

Handler = Callable[[int, FrameType | None], Any]
TERMINATING = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))
STOP_SIGNALS = (signal.SIGINT, *TERMINATING)


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


_hung_up = False  # a terminal hangs up once, but its SIGHUP reaches the session leader and the foreground group


def terminal_fds() -> tuple[int, ...]:
    """The standard output streams that are on a terminal now (after a hang-up isatty says no)."""
    fds = []
    for stream in (sys.stdout, sys.stderr):
        try:
            if os.isatty(stream.fileno()):
                fds.append(stream.fileno())
        except (AttributeError, OSError, ValueError):  # no real file behind it (a test's capture), or closed
            continue
    return tuple(fds)


def leave_lost_terminal(fds: tuple[int, ...]) -> None:
    """Point these file descriptors (the ones that were on the terminal) at /dev/null."""
    for fd in fds:
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, fd)
            os.close(devnull)
        except OSError:
            continue


@contextlib.contextmanager
def handled(handler: Handler, signals: tuple[int, ...] = STOP_SIGNALS) -> Iterator[bool]:
    """Run `handler(signum, frame)` on each of `signals` inside the block, and restore the previous handlers
    after it. Only the main thread may set handlers: elsewhere nothing changes, and the block gets False.
    A SIGHUP points the streams that were on the terminal at /dev/null first, and comes once: a repeat is
    the same hang-up, reported twice."""
    if threading.current_thread() is not threading.main_thread():
        yield False
        return
    on_terminal = terminal_fds()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        global _hung_up
        if signum == getattr(signal, "SIGHUP", None):
            if _hung_up:
                return
            _hung_up = True
            leave_lost_terminal(on_terminal)
        handler(signum, frame)

    previous: dict[int, Any] = {}
    try:
        for signum in signals:
            previous[signum] = signal.signal(signum, on_signal)
        yield True
    finally:
        for signum, old in previous.items():
            if old is not None:  # None: a handler not set from Python, which cannot be put back
                signal.signal(signum, old)


def _as_sigint(signum: int, frame: FrameType | None) -> None:
    current = signal.getsignal(signal.SIGINT)
    if callable(current):  # the press loop's stop request, or Python's default (KeyboardInterrupt)
        current(signum, frame)
        return
    # SIGINT ignored (a job started in the background of a script) or left to the OS: a stop signal still stops
    raise KeyboardInterrupt(f"stopped by {signal_name(signum)}")


@contextlib.contextmanager
def as_ctrl_c() -> Iterator[None]:
    """SIGTERM and SIGHUP, inside the block, do what SIGINT does at the moment they arrive."""
    with handled(_as_sigint, TERMINATING):
        yield

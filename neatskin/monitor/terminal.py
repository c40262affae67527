"""The monitor page's printer terminal: a line typed on the page, sent through the console's commands (raw
G-code, jog, `pos`, `endstops`, ...) over neatskin.marlin's driver, the reply shown beside it.

The rule (the campaign runs the printer; two hosts on one printer is a crash waiting to happen):
- only with the control token, only when the monitor was started with `--printer-port`;
- refused while a process holds the campaign folder's lock: a running campaign, paused or not, owns the printer
  (its runner keeps the port; a pause lifts and waits, it does not let go);
- the port is opened exclusively (flock, as every driver does): if another program holds it, the terminal says so;
- the terminal lets the port go after IDLE_RELEASE_S without a command, and at once when it finds a campaign
  holding the folder, so a campaign started later is not locked out by a forgotten page.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neatskin.errors import NeatskinError

log = logging.getLogger(__name__)

IDLE_RELEASE_S = 60.0
MAX_LINE_CHARS = 200  # a console line, not a program: `neatskin printer send` streams files


class TerminalRefused(Exception):
    """The terminal will not send this line; the message says why and what to do (HTTP 409 on the page)."""


@dataclass
class TerminalReply:
    line: str
    reply: list[str]
    port: str


class PrinterTerminal:
    """One console session over the printer port, opened on the first line and released when idle."""

    def __init__(
        self,
        folder: Path,
        port: str,
        *,
        baud_rate: int = 115200,
        connect_timeout_s: float = 5.0,
        opener: Callable[[str, int, float], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.folder = Path(folder)
        self.port = port
        self.baud_rate = baud_rate
        self.connect_timeout_s = connect_timeout_s
        self._opener = opener or _open_driver
        self._clock = clock
        self._lock = threading.Lock()
        self._driver: Any = None
        self._session: Any = None
        self._last_used = 0.0

    def campaign_holder(self) -> str | None:
        """Who holds the campaign folder (a live process), or None."""
        from neatskin.datasets.lock import lock_state

        held, holder = lock_state(self.folder)
        return str(holder or "a running campaign") if held else None

    def send(self, line: str) -> TerminalReply:
        text = line.strip()
        if not text:
            raise TerminalRefused("an empty line: type a G-code line (M114) or a console command (help)")
        if len(text) > MAX_LINE_CHARS or any(ord(c) < 32 for c in text):
            raise TerminalRefused(f"one line of at most {MAX_LINE_CHARS} printable characters, please")
        with self._lock:
            holder = self.campaign_holder()
            if holder is not None:
                self._release()
                raise TerminalRefused(
                    f"the campaign holds the printer ({holder}): the terminal works when no campaign runs "
                    "(finished, stopped and exited, or crashed); pause is not enough, the runner keeps the port"
                )
            if self._session is None:
                self._connect()
            try:
                reply = self._session.handle(text)
            except (NeatskinError, ValueError) as exc:
                reply = [f"error: {exc}"]
            self._last_used = self._clock()
            return TerminalReply(text, list(reply), self.port)

    def release_if_idle(self) -> None:
        """Let the port go after IDLE_RELEASE_S without a line (the server calls this between requests)."""
        with self._lock:
            if self._driver is not None and self._clock() - self._last_used > IDLE_RELEASE_S:
                self._release()

    def close(self) -> None:
        with self._lock:
            self._release()

    @property
    def connected(self) -> bool:
        return self._driver is not None

    def _connect(self) -> None:
        from neatskin.monitor.console import ConsoleSession

        try:
            self._driver = self._opener(self.port, self.baud_rate, self.connect_timeout_s)
        except NeatskinError as exc:
            raise TerminalRefused(f"cannot open the printer on {self.port}: {exc}") from exc
        self._session = ConsoleSession(self._driver)

    def _release(self) -> None:
        if self._driver is not None:
            try:
                self._driver.close()
            except Exception as exc:  # closing a dead port must not keep the terminal from reopening it
                log.info("closing the printer port: %s", exc)
        self._driver = self._session = None


def _open_driver(port: str, baud_rate: int, connect_timeout_s: float):
    from neatskin.marlin.driver import MarlinDriver

    driver = MarlinDriver.open(port, baud_rate)
    try:
        driver.connect(connect_timeout_s)
    except BaseException:
        driver.close()
        raise
    return driver

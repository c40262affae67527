"""A scripted Marlin peer for byte-level protocol tests, in the manner of PyMeasure's expected_protocol.

`ScriptedPeer(script)` serves a real pty: for each step it reads exactly one line the host
writes and compares it byte for byte with the expectation, then writes the scripted replies.
Steps: `(expected_line_bytes, replies)`, replies bytes or a list of bytes and pauses (seconds); `(None, replies)` writes without waiting for a
line (a spontaneous reply, e.g. a `start` in mid-session); `expected` may also be a callable
that returns True for an acceptable line. Mismatches are collected, never raised in the thread;
`check()` raises AssertionError listing them, or if the script did not run to its end.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

from neatskin.sim.pty import open_pty, read_available, write_all

Step = tuple[bytes | Callable[[bytes], bool] | None, bytes | list[bytes | float]]


class ScriptedPeer:
    def __init__(self, script: Sequence[Step], *, line_timeout_s: float = 5.0, delay_s: float = 0.0) -> None:
        self.script = list(script)
        self.line_timeout_s = line_timeout_s
        self.delay_s = delay_s
        self.pty = open_pty()
        self.path = self.pty.path
        self.received: list[bytes] = []
        self.problems: list[str] = []
        self.steps_done = 0
        self._stop = threading.Event()
        self._buffer = b""
        self._thread = threading.Thread(target=self._run, name="scripted-peer", daemon=True)
        self._thread.start()

    def _next_line(self) -> bytes | None:
        end = time.monotonic() + self.line_timeout_s
        while b"\n" not in self._buffer:
            if self._stop.is_set() or time.monotonic() > end:
                return None
            self._buffer += read_available(self.pty.master_fd, 0.01)
        line, self._buffer = self._buffer.split(b"\n", 1)
        self.received.append(line + b"\n")
        return line + b"\n"

    def _run(self) -> None:
        for index, (expected, replies) in enumerate(self.script):
            if expected is not None:
                line = self._next_line()
                if line is None:
                    self.problems.append(f"step {index}: expected {expected!r}, the host sent nothing")
                    return
                ok = expected(line) if callable(expected) else line == expected
                if not ok:
                    self.problems.append(f"step {index}: expected {expected!r}, got {line!r}")
            if self.delay_s:
                time.sleep(self.delay_s)
            for part in replies if isinstance(replies, list) else [replies]:
                if isinstance(part, (int, float)):
                    time.sleep(part)  # a pause inside the replies: a long command, a keep-alive interval
                elif part:
                    write_all(self.pty.master_fd, part)
            self.steps_done = index + 1

    def extra_lines(self, wait_s: float = 0.1) -> list[bytes]:
        """Lines the host wrote after the script ended (there should usually be none)."""
        self._thread.join(timeout=self.line_timeout_s * (len(self.script) + 1))
        end = time.monotonic() + wait_s
        while time.monotonic() < end:
            self._buffer += read_available(self.pty.master_fd, 0.01)
        return [line + b"\n" for line in self._buffer.split(b"\n")[:-1]]

    def check(self) -> None:
        self._thread.join(timeout=self.line_timeout_s * (len(self.script) + 1))
        if self.problems or self.steps_done != len(self.script):
            raise AssertionError(
                f"protocol mismatch after {self.steps_done}/{len(self.script)} steps: "
                f"{self.problems}; host sent {self.received}"
            )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.pty.close()

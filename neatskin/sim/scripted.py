"""Marlin peers for protocol tests: a byte-exact scripted peer, and a small firmware in three resend dialects.

`DialectFirmware` (sans-IO) and `FirmwareOnPty` (it, served on a real pty) answer in the Marlin 1,
Marlin 2 or Repetier/OctoPrint resend dialect, refuse chosen lines, or turn hostile (a boot loop,
`Resend: 0` for ever, doubled oks, garbage, silence); see DialectFirmware.

`ScriptedPeer(script)`, in the manner of PyMeasure's expected_protocol, serves a real pty: for each step it reads exactly one line the host
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


# ---- a small firmware in three resend dialects, and hostile peers -------------------------------------

DIALECTS = ("marlin1", "marlin2", "repetier")


class DialectFirmware:
    """A minimal line-numbered firmware, sans-IO: `feed(bytes)` returns the reply bytes, `executed` what ran.

    dialect "marlin1": `Error:checksum mismatch, Last Line: L` / `Resend: L+1` / `ok`;
    "marlin2": the same without the `ok`; "repetier" (Repetier, OctoPrint's Virtual Printer):
    `Error: Checksum mismatch` / `Resend:L+1` / `ok`, no "Last Line:" text, and
    `Error: expected line L+1 got N` for a line out of order. `reject={n: k}` refuses line n
    k times as if its checksum were corrupted on the wire. M118 E1 echoes (`echo:<text>`), M114 answers
    `ok X:.. Y:.. Z:..` (OctoPrint's form). Hostile modes replace the answer to every line:
    "start" (a boot loop), "resend0" (`Resend: 0` for ever), "double_ok" (every ok twice; the
    second is returned by the next feed, as a separate read), "garbage", "silent", "ahead" (`ok N<n+1000> P15 B3`:
    an ok naming a line never sent).
    """

    def __init__(self, dialect: str = "marlin2", *, reject: dict[int, int] | None = None, mode: str = "") -> None:
        if dialect not in DIALECTS:
            raise ValueError(f"dialect must be one of {DIALECTS}, got {dialect!r}")
        self.dialect = dialect
        self.reject = dict(reject or {})
        self.mode = mode
        self.last_n = 0
        self.executed: list[str] = []
        self.lines_received = 0
        self._rx = b""
        self._later = b""

    def feed(self, data: bytes) -> bytes:
        self._rx += data
        out = self._later
        self._later = b""
        while b"\n" in self._rx:
            raw, self._rx = self._rx.split(b"\n", 1)
            text = raw.decode("ascii", "replace").strip()
            if text:
                self.lines_received += 1
                out += self._line(text)
        return out

    def _line(self, text: str) -> bytes:
        mode = self.mode
        if mode == "silent":
            return b""
        if mode == "start":
            return b"start\n"
        if mode == "resend0":
            return b"Resend: 0\n"
        if mode == "garbage":
            return b"\x00\xff#!garbage " + text[::-1].encode() + b"\n"
        if mode == "ahead":  # out of step: every line acknowledged as one 1000 later (ADVANCED_OK's form)
            number = text.split(" ", 1)[0][1:]
            return f"ok N{int(number) + 1000 if number.isdigit() else 1000} P15 B3\n".encode()
        body, _, check = text.partition("*")
        head, _, command = body.partition(" ")
        n = int(head[1:]) if head.startswith("N") and head[1:].isdigit() else None
        if n is None:
            self.executed.append(text)
            return self._ok()
        if "M110" in command:
            self.last_n = n
            self.executed.append(command)
            return self._ok()
        if self.reject.get(n, 0) > 0:
            self.reject[n] -= 1
            return self._refuse(checksum_error=True, got=n)
        if n != self.last_n + 1:
            if self.dialect == "marlin2" and self.last_n - 1 <= n <= self.last_n:
                return b""  # Marlin 2.1 drops a repeat without a word
            return self._refuse(checksum_error=False, got=n)
        self.last_n = n
        self.executed.append(command)
        if command.startswith("M118 E1 "):
            return f"echo:{command[8:]}\n".encode() + self._ok()
        if command == "M114":
            return self._ok(" X:1.00 Y:2.00 Z:3.00 E:0.00 Count: A:0 B:0 C:0")
        if command == "M105":
            return self._ok(" T:25.00 /0.00 B:24.00 /0.00")
        return self._ok()

    def _ok(self, data: str = "") -> bytes:
        reply = f"ok{data}\n".encode()
        if self.mode == "double_ok":
            self._later += b"ok\n"
        return reply

    def _refuse(self, *, checksum_error: bool, got: int) -> bytes:
        last = self.last_n
        if self.dialect == "repetier":
            error = "Error: Checksum mismatch" if checksum_error else f"Error: expected line {last + 1} got {got}"
            return f"{error}\nResend:{last + 1}\nok\n".encode()
        what = "checksum mismatch" if checksum_error else "Line Number is not Last Line Number+1"
        reply = f"Error:{what}, Last Line: {last}\nResend: {last + 1}\n"
        if self.dialect == "marlin1":
            reply += "ok\n"
        return reply.encode()


class FirmwareOnPty:
    """Serve a DialectFirmware on a real pty from a thread (`.path` for the host); `delay_s` before each answer."""

    def __init__(self, firmware: DialectFirmware, *, boot: bytes = b"start\n", split_s: float = 0.0) -> None:
        self.firmware = firmware
        self.split_s = split_s  # a pause between the answer and a delayed duplicate (double_ok): separate reads
        self.pty = open_pty()
        self.path = self.pty.path
        self._stop = threading.Event()
        if boot:
            write_all(self.pty.master_fd, boot)
        self._thread = threading.Thread(target=self._run, name="firmware-on-pty", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = read_available(self.pty.master_fd, 0.01)
            except OSError:
                return
            if not data:
                continue
            firmware = self.firmware
            later, firmware._later = firmware._later, b""
            try:
                if later:  # the duplicate of the previous ok, in a read of its own
                    write_all(self.pty.master_fd, later)
                    time.sleep(self.split_s)
                out = firmware.feed(data)
                if out:
                    write_all(self.pty.master_fd, out)
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.pty.close()

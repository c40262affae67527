"""The real Marlin firmware (built natively, ../shared/marlin) behind a pty, through a relay that can corrupt and drop.

`FirmwareRelay(binary).start()` runs the firmware with a raw pty as its stdin/stdout and relays
bytes, line by line, to a second raw pty whose path a host opens like a USB port. The relay keeps
a transcript of every line each way, and can corrupt the next host line that contains a text
(a checksum digit changed, as line noise does) or drop the next `ok` after a given host line (a
lost reply). With `M111 S1` the firmware echoes every command it executes (`echo:N12 G1 Z2*..`):
`executed()` reads them back, the exactly-once oracle from the firmware itself.
The firmware keeps its own flow control (its HAL reads stdin only into free ring space), so the
relay never drops a byte it was not told to.
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from neatskin.sim.pty import PtyPair, open_pty

#: Where the firmware lives relative to the repository: the parent's `shared/marlin`.
MARLIN_DIR_ENV = "NEATSKIN_MARLIN_DIR"
PLAIN = "marlin-native"
ADVANCED_OK = "marlin-native-advok"
_ECHO = re.compile(r"^echo:(?:N(\d+) )?(.*?)(?:\*\d+)?$")


def find_marlin_dir(repo: Path | None = None) -> Path | None:
    """The folder holding the firmware binaries: $NEATSKIN_MARLIN_DIR, else `shared/marlin` beside the
    repository (or beside the folder holding it, for a git worktree); None when absent."""
    env = os.environ.get(MARLIN_DIR_ENV)
    if env:
        return Path(env) if (Path(env) / PLAIN).is_file() else None
    repo = repo or Path(__file__).resolve().parents[2]
    for base in (repo.parent, repo.parent.parent):
        candidate = base / "shared" / "marlin"
        if (candidate / PLAIN).is_file():
            return candidate
    return None


@dataclass
class Faults:
    """What the relay does to the next matching line (each fault fires once)."""

    corrupt: list[str] = field(default_factory=list)  # host lines containing these texts get a digit changed
    drop_ok_after: list[str] = field(default_factory=list)  # after a host line containing this, drop the next ok
    _armed_drops: int = 0


class FirmwareRelay:
    """The firmware process, its pty, the host's pty and the relay thread between them."""

    def __init__(self, binary: str | os.PathLike[str], *, boot_wait_s: float = 10.0) -> None:
        self.binary = Path(binary)
        if not self.binary.is_file():
            raise FileNotFoundError(f"no Marlin firmware at {self.binary}")
        self.boot_wait_s = boot_wait_s
        self.faults = Faults()
        self.transcript: list[tuple[float, str, bytes]] = []  # (monotonic s, ">" host->fw or "<", line)
        self.dropped: list[bytes] = []
        self.corrupted: list[tuple[bytes, bytes]] = []
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._fw: PtyPair | None = None
        self._host: PtyPair | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.on_reply: Callable[[bytes], None] | None = None

    # ---- life cycle -----------------------------------------------------------------------------

    def start(self, *, wait_for_banner: bool = True) -> str:
        """Run the firmware and the relay; the host pty's path. Waits until the boot banner is out."""
        self._fw = open_pty()
        self._host = open_pty()
        self._proc = subprocess.Popen(
            [str(self.binary)],
            stdin=self._fw.slave_fd,
            stdout=self._fw.slave_fd,
            stderr=subprocess.DEVNULL,
            cwd="/tmp",  # it writes an eeprom file in its working folder
            close_fds=True,
        )
        self._stop.clear()
        self._thread = threading.Thread(target=self._relay, name=f"marlin-relay {self.binary.name}", daemon=True)
        self._thread.start()
        if wait_for_banner:
            self.wait_for(lambda line: line.startswith(b"echo:") and b"M301" in line or line == b"ok", self.boot_wait_s)
            time.sleep(0.3)  # the last lines of the settings report
        return self._host.path

    @property
    def path(self) -> str:
        assert self._host is not None, "start() first"
        return self._host.path

    def stop(self) -> None:
        self._stop.set()
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait(timeout=5)
            self._proc = None
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None
        for pair in (self._fw, self._host):
            if pair is not None:
                pair.close()
        self._fw = self._host = None

    def __enter__(self) -> FirmwareRelay:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- what the firmware said -------------------------------------------------------------------

    def replies(self) -> list[bytes]:
        """Every line the firmware wrote, in order, with its end of line (dropped ones included)."""
        with self._lock:
            return [line for _, d, line in self.transcript if d == "<"]

    def executed(self) -> list[tuple[int | None, str]]:
        """(line number, command) of every command the firmware echoed as executed (`M111 S1` on)."""
        out: list[tuple[int | None, str]] = []
        for raw in self.replies():
            text = raw.decode("ascii", "replace").strip()
            match = _ECHO.match(text)
            if not match or not _is_command(match.group(2)):
                continue
            out.append((int(match.group(1)) if match.group(1) else None, match.group(2).strip()))
        return out

    def wait_for(self, predicate: Callable[[bytes], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        seen = 0
        while time.monotonic() < end:
            lines = self.replies()
            if any(predicate(line.rstrip(b"\r\n")) for line in lines[seen:]):
                return True
            seen = len(lines)
            time.sleep(0.02)
        return False

    def send_raw(self, data: bytes) -> None:
        """Write bytes to the firmware directly, bypassing the host pty (a test's own command)."""
        assert self._fw is not None
        os.write(self._fw.master_fd, data)

    # ---- the relay ------------------------------------------------------------------------------

    def _relay(self) -> None:
        fw, host = self._fw, self._host
        assert fw is not None and host is not None
        from_host = b""
        from_fw = b""
        to_fw = b""
        to_host = b""
        while not self._stop.is_set():
            wants_w = [fd for fd, buf in ((fw.master_fd, to_fw), (host.master_fd, to_host)) if buf]
            try:
                readable, writable, _ = select.select([fw.master_fd, host.master_fd], wants_w, [], 0.05)
                for fd in writable:
                    if fd == fw.master_fd:
                        to_fw = to_fw[os.write(fd, to_fw) :]
                    else:
                        to_host = to_host[os.write(fd, to_host) :]
                if host.master_fd in readable and len(to_fw) < 4096:
                    from_host += os.read(host.master_fd, 4096)
                    *lines, from_host = from_host.split(b"\n")
                    for line in lines:
                        to_fw += self._from_host(line + b"\n")
                if fw.master_fd in readable:
                    from_fw += os.read(fw.master_fd, 4096)
                    *lines, from_fw = from_fw.split(b"\n")
                    for line in lines:
                        to_host += self._from_firmware(line + b"\n")
            except OSError:
                return

    def _from_host(self, line: bytes) -> bytes:
        now = time.monotonic()
        faults = self.faults
        with self._lock:
            for i, text in enumerate(faults.corrupt):
                if text.encode() in line:
                    del faults.corrupt[i]
                    bad = _corrupt(line)
                    self.corrupted.append((line, bad))
                    line = bad
                    break
            for i, text in enumerate(faults.drop_ok_after):
                if text.encode() in line:
                    del faults.drop_ok_after[i]
                    faults._armed_drops += 1
                    break
            self.transcript.append((now, ">", line))
        return line

    def _from_firmware(self, line: bytes) -> bytes:
        with self._lock:
            self.transcript.append((time.monotonic(), "<", line))
            if self.faults._armed_drops and line.rstrip(b"\r\n").split(b" ", 1)[0] == b"ok":
                self.faults._armed_drops -= 1
                self.dropped.append(line)
                return b""
        return line


def _corrupt(line: bytes) -> bytes:
    """The checksum's last digit changed (the line stays well formed, so Marlin says `checksum mismatch`)."""
    star = line.rfind(b"*")
    if star < 0:
        return line[:-2] + (b"0" if line[-2:-1] != b"0" else b"1") + line[-1:]
    end = len(line.rstrip(b"\r\n"))
    digit = line[end - 1 : end]
    return line[: end - 1] + (b"1" if digit != b"1" else b"2") + line[end:]


def _is_command(text: str) -> bool:
    head = text.split(" ", 1)[0]
    return len(head) >= 2 and head[0] in "GMT" and head[1:].replace(".", "").isdigit()

"""MarlinDriver: exactly-once, in-order G-code delivery to Marlin over any pyserial port object.

The driver is the command API over the sans-IO `LineProtocol` (linestate.py) and its live link
(link.py: the reader thread, the read right a waiting caller takes, the writes and the wire log):
it opens the port (exclusively), connects and closes sessions, and turns commands into jobs and
their endings into answers (`send`, `send_lines`, `position`, `endstops`, `sync`, `emergency_stop`,
`stop_after_line_in_flight`), raising CommandRejected for a refused command. All protocol decisions
(resends, lost-`ok` probes, deadlines, caps) live in the state machine; every wait ends when the
protocol finishes or fails the job, and the protocol has a deadline for every line. Halts, resets
and a dead port raise a MarlinError naming the last line acknowledged; after that nothing is sent
but an M112 on request.
"""

from __future__ import annotations

import collections
import errno
import os
import time
from collections.abc import Callable, Iterable
from os import PathLike
from typing import Any

from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import errors as E
from neatskin.marlin.commands import CommandParser, clean_command
from neatskin.marlin.jobs import Acknowledged, DriverConfig, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.marlin.link import Link
from neatskin.marlin.replies import Position, parse_m114, parse_m119
from neatskin.marlin.transport import Clock, SerialPort, channel_for

__all__ = ["DriverConfig", "MarlinDriver"]


class MarlinDriver:
    """Talk to Marlin over `port` (an unopened or open pyserial object: Serial, serial_for_url(...))."""

    def __init__(
        self,
        port: SerialPort,
        *,
        config: DriverConfig = DriverConfig(),
        profile: PrinterProfile | None = None,
        wire_log: str | PathLike[str] | None = None,
        clock: Clock = time.monotonic,
        rx_buffer_size: int | None = None,
    ) -> None:
        """rx_buffer_size: the firmware's RX_BUFFER_SIZE (the printer profile's `rx_buffer_size`; default:
        the profile's, else Marlin's stock 128): lines and probes in flight never hold more bytes."""
        self.port = port
        self.config = config
        self.profile = profile
        self.wire_log_path = wire_log
        self.clock = clock
        self._protocol = LineProtocol(config, profile, self.port_name, rx_buffer_size=rx_buffer_size)
        self._link = Link(self._protocol, config, clock, self.port_name)
        self._batch: list[Job] = []
        self._commands = CommandParser()

    @classmethod
    def open(cls, url: str, baud_rate: int = 115200, **kwargs: Any) -> MarlinDriver:
        """A driver on a port name or pyserial URL (`/dev/ttyUSB0`, `/dev/pts/3`, `loop://`, `socket://h:p`).

        A device port is opened exclusively (flock): a second process gets PortBusy, not a shared line."""
        import serial

        if "://" not in url and not os.path.exists(url):
            raise E.PortMissing("the device does not exist", port=url)
        try:
            port = serial.serial_for_url(url, baudrate=baud_rate, timeout=0.02, exclusive=True, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise E.PortDead(f"cannot use port {url!r}: {exc}", port=url) from exc
        return cls(port, **kwargs)

    # ---- what callers read ------------------------------------------------------------------

    @property
    def port_name(self) -> str:
        return str(getattr(self.port, "name", None) or getattr(self.port, "port", None) or "<port>")

    @property
    def stats(self) -> collections.Counter[str]:
        """Counters of this session: lines_sent, lines_resent, probes, busy, oks_swallowed, stray_oks..."""
        return self._protocol.stats

    @property
    def last_acknowledged(self) -> tuple[int | None, str | None]:
        """(line number, command) of the last line the firmware acknowledged."""
        return self._protocol.last_acked

    @property
    def actions(self) -> list[str]:
        return self._protocol.actions

    @property
    def unsolicited(self) -> collections.deque[str]:
        return self._protocol.unsolicited

    @property
    def commanded_position_mm(self) -> tuple[float | None, float | None, float | None]:
        """Where the lines sent so far put the tool (None: unknown), from the host's motion model."""
        x, y, z = list(self._protocol.motion.position_mm or [None, None, None])[:3]
        return x, y, z

    @property
    def commanded_absolute(self) -> bool:
        """Whether the lines sent so far leave the printer in absolute (G90) distance mode."""
        return bool(self._protocol.motion.absolute)

    @property
    def lines_in_flight(self) -> int:
        """Lines written whose `ok` has not come yet."""
        return self._protocol.in_flight

    @property
    def failure(self) -> E.MarlinError | None:
        """The error that ended the session, if any."""
        return self._protocol.failure

    @property
    def reader_wakeups(self) -> int:
        """Reads that ended (data, a deadline, a wake): nobody polls."""
        return self._link.reader_wakeups

    @property
    def caller_reads(self) -> int:
        """Of the reads, those a waiting caller made (the rest are the reader thread's)."""
        return self._link.caller_reads

    # ---- connect / close ----------------------------------------------------------------------

    def connect(self, boot_timeout_s: float | None = None) -> MarlinDriver:
        """Open the port, wait for `start` (or time out cleanly), and reset the line counter (M110 N0).

        Bounded: a boot loop or a printer that refuses M110 ends in ConnectFailed, silence in NoAnswer."""
        import serial

        self._link.stop()
        self._link.open_wire_log(self.wire_log_path)
        try:
            if not self.port.is_open:
                self.port.open()
            self.port.timeout = self.config.poll_s
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            if "exclusively lock" in str(exc) or "Resource temporarily unavailable" in str(exc):
                raise E.PortBusy(f"cannot open it exclusively: {exc}", port=self.port_name) from exc
            if "(25," in str(exc) or getattr(exc, "errno", None) == errno.ENOTTY:  # a file, /dev/null: no termios
                raise E.NotASerialPort(f"cannot configure it: {exc}", port=self.port_name) from exc
            if getattr(exc, "errno", None) == errno.EISDIR:  # a folder (`--port /tmp`): no device, no cable to check
                raise E.NotASerialPort(f"it is a folder: {exc}", port=self.port_name) from exc
            raise E.PortDead(f"cannot open: {exc}", port=self.port_name) from exc
        self._link.start(channel_for(self.port, self.clock), boot_timeout_s)
        return self

    def reconnect(self, boot_timeout_s: float | None = None) -> MarlinDriver:
        """After a PrinterReset (or any failure): start a new session. The printer must be homed again."""
        return self.connect(boot_timeout_s)

    def close(self) -> None:
        self._link.stop()
        try:
            self.port.close()
        except Exception:  # noqa: BLE001 - closing a dead port must not raise
            pass
        self._link.close_wire_log()

    def __enter__(self) -> MarlinDriver:
        return self.connect() if not self._link.running else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- public API ---------------------------------------------------------------------------

    def send(self, command: str, *, strict: bool = True) -> list[str]:
        """Send one command and wait for its `ok`; the reply lines before the `ok` (M114 text, echoes),
        then any data carried on the `ok` line itself (`ok T:25.00 /0.00` gives "T:25.00 /0.00").

        strict: raise CommandRejected when Marlin refuses it (`Unknown command`, `Home XYZ First`).
        Once the printer has sent an unexplained `ok`, each command is confirmed by a probe's echo.
        """
        command = clean_command(command)
        job = Job(command)
        jobs = [job]
        if self._protocol.confirming:
            jobs.append(Job("", barrier=True))
        self._link.submit(jobs)
        try:
            self._link.wait(jobs[-1])
            result = self._link.wait(job)  # ended already: the barrier (if any) came after it
        finally:
            self._link.forget(jobs)
        if strict and result.rejected:
            raise E.CommandRejected(
                f"{result.rejected!r} in answer to N{result.line} {command!r}",
                last_line=result.line,
                last_command=command,
                port=self.port_name,
            )
        return list(result.replies)

    def send_lines(
        self, lines: Iterable[str], progress: Callable[[int, int], None] | None = None, *, source: str = "<lines>"
    ) -> int:
        """Send a program in order, exactly once each; returns the number of commands sent.

        Comments and blank lines are dropped; every line is parsed first, so a syntax error
        raises before anything is sent. progress(done, total) is called as lines are acknowledged.
        A refused command stops the batch (CommandRejected) with the rest unsent. With
        config.confirm_batches (or once the printer was seen duplicating an `ok`) the batch ends with
        a probe (`M118 E1 neatskin-probe N`) whose echo proves that every line ran, so a duplicated
        `ok` cannot make this return before the printer ran the batch.
        """
        program = self._commands.parse_batch(lines, source)  # the protocol sizes deadlines from these
        if not program:
            return 0
        batch = object()
        jobs = [Job(command, line, batch) for command, line in program]
        self._link.forget(self._batch)  # the previous batch's results are no longer asked for
        self._batch = jobs
        last = jobs[-1]
        if self._protocol.confirming:
            last = Job("", batch=batch, barrier=True)
        self._link.submit(jobs if last is jobs[-1] else [*jobs, last])

        shown = [0.0]

        def report() -> None:
            now = self.clock()
            if progress is not None and now - shown[0] >= 0.1:
                shown[0] = now
                progress(self.batch_acknowledged(), len(jobs))

        try:
            self._link.wait(last, report)
        finally:
            if last is not jobs[-1]:
                self._link.forget([last])
        for job in jobs:
            result = self._link.result(job)
            if isinstance(result, Acknowledged) and result.rejected:
                raise E.CommandRejected(
                    f"{result.rejected!r} in answer to N{result.line} {job.command!r}",
                    last_line=result.line,
                    last_command=job.command,
                    port=self.port_name,
                )
        if progress is not None:
            progress(len(jobs), len(jobs))
        return len(jobs)

    def batch_acknowledged(self) -> int:
        """How many commands of the latest send_lines batch the printer acknowledged (a prefix, in order)."""
        return self._link.acknowledged_prefix(self._batch)

    def stop_after_line_in_flight(self, timeout_s: float | None = None) -> int:
        """Take back every command not yet written, wait for the line in flight; the number acknowledged.

        For Ctrl-C: nothing new goes out; the session stays usable (a lift may follow)."""
        self._link.take_back_and_drain(timeout_s if timeout_s is not None else self.config.max_busy_s)
        return self.batch_acknowledged()

    def sync(self) -> None:
        """M400: return when every queued move has finished."""
        self.send("M400")

    def position(self) -> Position:
        """M114, parsed (`X:.. Y:.. Z:..` on its own line or on the `ok`); BadReply if no position came."""
        replies = self.send("M114")
        try:
            return parse_m114(replies)
        except ValueError as exc:
            n, cmd = self._protocol.last_acked
            raise E.BadReply(str(exc), last_line=n, last_command=cmd, port=self.port_name) from exc

    def endstops(self) -> dict[str, bool]:
        """M119, parsed: {"x_min": False, "z_min": True, ...} (True = triggered); BadReply if none came."""
        replies = self.send("M119")
        try:
            return parse_m119(replies)
        except ValueError as exc:
            n, cmd = self._protocol.last_acked
            raise E.BadReply(str(exc), last_line=n, last_command=cmd, port=self.port_name) from exc

    def emergency_stop(self) -> None:
        """Send M112 at once, ahead of anything queued; the session ends (EmergencyStopped)."""
        self._link.emergency_stop()

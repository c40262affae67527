"""The driver's failures, each a HardwareError that names the last line the printer acknowledged.

After any of these the driver sends nothing more (but an M112 if asked): the probe's state is
unknown, and a campaign must stop, re-home and resume from its own records.
"""

from __future__ import annotations

from neatskin.errors import HardwareError


class MarlinError(HardwareError):
    """A failure on the Marlin line. `last_line` / `last_command`: the last line acknowledged."""

    what = "the printer failed"
    consequence = "the probe's state is unknown and nothing more was sent"
    fix = "check the printer and its cable, reset it, home it (G28) and resume the campaign"

    def __init__(
        self, detail: str, *, last_line: int | None = None, last_command: str | None = None, port: str | None = None
    ) -> None:
        self.detail = detail
        self.last_line = last_line
        self.last_command = last_command
        self.port = port
        where = f" on {port}" if port else ""
        if last_line is None:
            confirmed = "no line of this session was acknowledged"
        else:
            confirmed = f"the last line acknowledged was N{last_line} {last_command!r}"
        super().__init__(f"{self.what}{where}: {detail}; {confirmed}; {self.consequence} (fix: {self.fix})")


class PrinterHalted(MarlinError):
    what = "the printer halted"
    fix = "read the printer's error, clear its cause, reset the printer (or M999 after a Stop), home (G28) and resume"


class PrinterReset(MarlinError):
    what = "the printer reset in mid-session"
    fix = (
        "the printer rebooted (power, USB or watchdog): check its power supply and USB cable, then run the "
        "command again (a campaign: neatskin campaign resume FOLDER, which homes first; from Python: "
        "driver.reconnect(), then G28)"
    )


class PortDead(MarlinError):
    what = "the serial port died"
    fix = "check the USB cable and the port name, then reconnect"


class PortMissing(PortDead):
    """The port never opened: no such device. Nothing was sent, so the probe has not moved."""

    what = "no serial port"
    consequence = "nothing was sent"
    fix = "check the port name (ls /dev/ttyUSB* /dev/ttyACM*) and that the printer is plugged in and powered"

    def __init__(self, detail: str, *, port: str | None = None, **kwargs: object) -> None:
        MarlinError.__init__(self, detail, port=port)
        # a port that never opened has no session: say only what is wrong and how to fix it
        Exception.__init__(self, f"{self.what} {port!r}: {detail}; {self.consequence} (fix: {self.fix})")


class NoAnswer(MarlinError):
    what = "the printer does not answer"
    fix = "check that the port is the printer's, the baud rate matches the firmware, and the printer is powered"


class ResendLoop(MarlinError):
    what = "the line is too noisy"
    fix = "the printer asked for the same line again and again: check the cable, lower the baud rate or add a ferrite"


class CommandRejected(MarlinError):
    what = "the printer refused a command"
    consequence = "it did not run it; the rest of its batch was not sent"
    fix = "correct the G-code (home with G28 before moving; use commands this firmware knows)"


class EmergencyStopped(MarlinError):
    what = "emergency stop (M112) was sent"
    fix = "reset the printer, home (G28) and resume"


class ConnectFailed(MarlinError):
    what = "the printer would not start a session"
    fix = (
        "the printer keeps rebooting or refusing `M110 N0`: check its power supply and USB cable, "
        "that the baud rate matches the firmware, and that no other program talks to it"
    )


class OutOfStep(MarlinError):
    """An `ok N..` named a line the host never sent in this session: the two disagree on what ran."""

    what = "the printer and the host are out of step"
    fix = (
        "the printer acknowledged a line number this host never sent: make sure no other program (OctoPrint, "
        "Pronterface, a second neatskin) talks to the printer, reset it, home (G28) and run the command again "
        "(a campaign: neatskin campaign resume FOLDER)"
    )


class NotASerialPort(PortMissing):
    """The port is no terminal (a plain file, /dev/null: it opened; a folder: it did not): nothing was sent, no cable
    to check."""

    what = "not a serial port"
    fix = (
        "give the printer's serial device (ls /dev/ttyUSB* /dev/ttyACM*), or the pty that `neatskin sim printer` "
        "prints, not a file or a folder"
    )


class PortBusy(PortMissing):
    """Another process holds the port (opened exclusively): nothing was sent."""

    what = "the serial port is in use"
    fix = "another program (a second neatskin, OctoPrint, Pronterface) holds it: close that program, then retry"


class BadReply(MarlinError):
    what = "the printer's reply could not be read"
    consequence = "the command ran, but its answer is unusable"
    fix = "check that the firmware is Marlin (or compatible) and that the line is not noisy"


class Interrupted(MarlinError):
    what = "sending was interrupted"
    consequence = "lines not yet sent were not sent"
    fix = "continue from the last acknowledged line"


class WireLogFailed(MarlinError):
    what = "the wire log could not be written"
    consequence = "the printer line itself was fine; nothing more was sent, so the log stays complete"
    fix = "free disk space or give the wire log a writable path, then resume"

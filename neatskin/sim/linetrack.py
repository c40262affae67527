"""A real printer's probe trajectory from what crosses its serial line: the commanded program, its acknowledgements
and the printer's M114 reports (hardware in the loop: a real printer, the simulated skin and DAQ).

`LineTracker` wraps the campaign's driver. Every batch the press loop sends goes to the printer first; once the
printer has acknowledged all of it, the same lines run on a shadow of the firmware (sim.firmware.MarlinCore, the
one machine model the dry run's printer uses, on a virtual clock), so the moves the simulated skin is pressed along
are the program's own, timed by the planner model, and a press sees exactly the trajectory a dry run of the same
program would. After a batch that ends in `M400` (the printer idle: every move done) the tracker asks the printer
where it is (M114) and compares it with where the shadow says the program put it: a printer that is not where
its program says (lost steps, a different home, a skipped line) stops the campaign with a HardwareError rather than
labelling presses with positions the probe never had.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Protocol

from neatskin.errors import HardwareError
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin.replies import Position
from neatskin.sim.firmware import MarlinCore, VirtualClock
from neatskin.sim.motion import Segment

# M114 prints 2 decimals (0.005 mm rounding) and the steppers quantise to 1/80 or 1/400 mm: a printer where its
# program put it reads within this of the commanded point
POSITION_TOLERANCE_MM = 0.02
_STEP_CAP = 1_000_000  # commands one batch may run on the shadow: a cap, so a bug cannot spin forever


class TrackedDriver(Protocol):
    """What the tracker needs of neatskin.marlin.driver.MarlinDriver."""

    def send_lines(self, lines: Iterable[str], *, source: str = ...) -> object: ...

    def position(self) -> Position: ...


class LineTracker:
    """The press loop's driver (send_lines) and the simulated recorder's printer (now_s, segments) in one."""

    def __init__(self, driver: TrackedDriver, profile: PrinterProfile, *, check_position: bool = True) -> None:
        self.driver = driver
        self.profile = profile
        self.check_position = check_position
        self.shadow = MarlinCore(profile, clock=VirtualClock())  # unbounded rx: it takes a whole batch at once
        self.position_checks = 0  # M114 reports compared with the shadow
        self.max_position_error_mm = 0.0
        # (shadow, printer) positions after each G28 where the firmware's homing left the probe elsewhere
        self.homing_corrections: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = []

    def send_lines(self, lines: Iterable[str], *, source: str = "<lines>") -> int:
        """Send to the printer (exactly once each, returning when it acknowledged the last), then run the
        same lines on the shadow; after a batch ending in M400, check the printer's M114 against the shadow."""
        batch = [line for line in lines]
        sent = self.driver.send_lines(batch, source=source)
        commands = [_command(line) for line in batch]
        commands = [c for c in commands if c]
        self._shadow_run(commands)
        if self.check_position and commands and commands[-1].split()[0].upper() == "M400" and self._homed():
            homed = any(c.split()[0].upper() == "G28" for c in commands)
            self._check_position(source, follow=homed)
        return int(sent) if isinstance(sent, int) else len(commands)

    def now_s(self) -> float:
        """The program's clock: the shadow's virtual seconds (moves queued, M400 and G4 waited for)."""
        return self.shadow.clock.now()

    def segments(self, t0_s: float = 0.0) -> list[Segment]:
        """The commanded moves from the one the probe rests after at t0_s on (sim.printer.SimulatedPrinter's)."""
        return self.shadow.timeline.segments_from(t0_s)

    def commanded_mm(self) -> tuple[float, float, float]:
        """Where the program has put the probe once its queued moves are done (printer frame, mm)."""
        return self.shadow.timeline.end_mm

    def _homed(self) -> bool:
        return self.shadow.homed_all

    def _shadow_run(self, commands: list[str]) -> None:
        if not commands:
            return
        core = self.shadow
        core.receive("".join(c + "\n" for c in commands).encode("ascii"))
        for _ in range(_STEP_CAP):
            core.step()  # virtual clock: never waits, only jumps
            core.take_output()
            if not core.queue and not core.rx:
                return
        raise HardwareError(f"the printer's shadow did not finish {len(commands)} commands: a bug, not the printer")

    def _check_position(self, source: str, *, follow: bool = False) -> None:
        """Compare the printer's M114 with the shadow. `follow` (after a G28): where homing leaves the probe is the
        firmware's to say (Z_AFTER_HOMING, the endstops' positions), so the shadow moves there, a correction move
        the recorded presses start from; anywhere else a difference is the printer's fault."""
        reported = self.driver.position()
        want = self.commanded_mm()
        got = (reported.x_mm, reported.y_mm, reported.z_mm)
        error = math.dist(want, got)
        if follow and error > POSITION_TOLERANCE_MM:
            self.homing_corrections.append((want, got))
            self._shadow_run([f"G0 X{got[0]:.3f} Y{got[1]:.3f} Z{got[2]:.3f}", "M400"])
            want = self.commanded_mm()
            error = math.dist(want, got)
        self.position_checks += 1
        self.max_position_error_mm = max(self.max_position_error_mm, error)
        if error > POSITION_TOLERANCE_MM:
            raise HardwareError(
                f"after {source} the printer reports X{got[0]:.2f} Y{got[1]:.2f} Z{got[2]:.2f} but its program put "
                f"the probe at X{want[0]:.3f} Y{want[1]:.3f} Z{want[2]:.3f} ({error:.3f} mm off, more than "
                f"{POSITION_TOLERANCE_MM} mm): check the printer's homing and steps/mm against its profile"
            )


def _command(line: str) -> str:
    """The command of a program line: comments and surrounding blanks dropped (as the driver sends it)."""
    return line.split(";", 1)[0].strip()

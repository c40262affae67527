"""`neatskin printer console`: an interactive Marlin console for calibrating by hand (history and line editing
from prompt_toolkit; every line goes through neatskin.marlin.driver.MarlinDriver).

The commands live in `ConsoleSession.handle` (a line in, text lines out), so they are tested without a
terminal; `run_console` is the prompt_toolkit shell around it. Commands:

  x+ [MM] / x- / y+ / y- / z+ / z-   jog by MM (default: the current step), relative, and wait for the move;
                                     keys: Alt+Left/Right (X), Alt+Up/Down (Y), Alt+PageUp/PageDown (Z);
                                     a z- that would end below the skin surface (the profile's, or the
                                     lowest calibration point taken) is refused: `z- MM!` confirms it;
                                     a jog the printer cut short (a soft limit) says so
  step MM                            the jog step (0.1, 1, 10 ...)
  pos | m114                         where the probe is (M114, printer frame)
  endstops | m119                    endstop states (M119)
  home                               G28
  point SX SY                        confirm: the probe touches sensor point (SX, SY) here (M114 taken now)
  points / undo                      the points so far / drop the last one
  calibration                        the [calibration] block fitted to the points, and the equivalent
                                     `neatskin gcode calibrate --point ...` command
  save [FILE]                        write the [calibration] block to FILE
  G0 ..., M..., anything else        sent as is; the printer's reply is printed. A G0/G1 whose Z ends below
                                     the skin surface is refused as a z- jog is: end the line with `!` to
                                     send it (G91 typed here makes its Z relative; until then absolute,
                                     Marlin's boot mode, which can only refuse more, never less)
  help, quit

Ctrl-C while a command runs halts motion by waiting and lifting, not by M410: the moves in flight finish
(a console sends only short jogs), then Z rises by `lift_mm`, and at least to `lift_mm` above the skin
surface when it is known, and the position is printed. M410 would stop the
steppers without deceleration and lose their position (Marlin then needs G28, which with a flat probe resting
over the skin may drive it into the silicone); a second Ctrl-C during the wait sends M112 (emergency stop).
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from neatskin.errors import ConfigError, NeatskinError

log = logging.getLogger(__name__)

PROMPT = "marlin> "
DEFAULT_STEP_MM = 1.0
LIFT_MM = 5.0
JOG_FEED_MM_MIN = {"X": 3000.0, "Y": 3000.0, "Z": 300.0}
_JOG = re.compile(r"^([xyz])([+-])\s*(\d+(?:\.\d*)?)?(!?)$", re.IGNORECASE)


class PositionLike(Protocol):
    @property
    def x_mm(self) -> float: ...

    @property
    def y_mm(self) -> float: ...

    @property
    def z_mm(self) -> float: ...


class ConsoleDriver(Protocol):
    """What the console needs of neatskin.marlin.driver.MarlinDriver."""

    def send(self, command: str, *, strict: bool = True) -> list[str]: ...

    def position(self) -> PositionLike: ...

    def endstops(self) -> dict[str, bool]: ...

    def emergency_stop(self) -> None: ...


@dataclass(frozen=True)
class ReferencePoint:
    sensor_x_mm: float
    sensor_y_mm: float
    printer_x_mm: float
    printer_y_mm: float
    printer_z_mm: float

    def as_cli(self) -> str:
        return ",".join(
            f"{v:g}"
            for v in (self.sensor_x_mm, self.sensor_y_mm, self.printer_x_mm, self.printer_y_mm, self.printer_z_mm)
        )


def _fmt_position(p: PositionLike) -> str:
    return f"X{p.x_mm:.3f} Y{p.y_mm:.3f} Z{p.z_mm:.3f}"


def calibration_block(points: list[ReferencePoint]) -> list[str]:
    """The [calibration] block `neatskin gcode calibrate` prints for these points, with its residuals."""
    from neatskin.gcode.calibration import fit_calibration

    fit = fit_calibration(
        [[p.sensor_x_mm, p.sensor_y_mm] for p in points],
        [[p.printer_x_mm, p.printer_y_mm, p.printer_z_mm] for p in points],
        source="console points",
    )
    c = fit.calibration
    return [
        "[calibration]",
        f"offset_x_mm = {c.offset_x_mm:.3f}",
        f"offset_y_mm = {c.offset_y_mm:.3f}",
        f"rotation_deg = {c.rotation_deg:.4f}",
        f"surface_z_mm = {c.surface_z_mm:.3f}",
        f"# residual: rms {fit.rms_mm:.3f} mm, max {fit.max_mm:.3f} mm (xy); surface z spread {fit.z_spread_mm:.3f} mm",
        "# from: neatskin gcode calibrate " + " ".join(f"--point {p.as_cli()}" for p in points),
    ]


class ConsoleSession:
    """The console's commands over a driver; `handle(line)` returns the lines to print."""

    def __init__(
        self,
        driver: ConsoleDriver,
        *,
        calibration_out: Path | None = None,
        lift_mm: float = LIFT_MM,
        surface_z_mm: float | None = None,
    ) -> None:
        """surface_z_mm: the skin's surface in printer Z (a profile's calibration.surface_z_mm); without it,
        the lowest calibration point taken in this session is the surface."""
        self.driver = driver
        self.profile_surface_z_mm = surface_z_mm
        self.step_mm = DEFAULT_STEP_MM
        self.points: list[ReferencePoint] = []
        self.calibration_out = calibration_out
        self.lift_mm = lift_mm
        self.done = False
        self.relative = False  # a G91 typed in this session (the console's own jogs restore G90)

    def handle(self, line: str) -> list[str]:
        text = line.strip()
        if not text or text.startswith(";"):
            return []
        word, _, rest = text.partition(" ")
        command = word.lower()
        jog = _JOG.match(text.replace(" ", ""))
        if jog:
            return self.jog(jog.group(1).upper(), jog.group(2), jog.group(3), confirmed=bool(jog.group(4)))
        handler: Callable[[str], list[str]] | None = {
            "help": self._help,
            "step": self._step,
            "pos": lambda _: [_fmt_position(self.driver.position())],
            "m114": lambda _: [_fmt_position(self.driver.position())],
            "endstops": self._endstops,
            "m119": self._endstops,
            "home": lambda _: self._raw("G28") + [_fmt_position(self.driver.position())],
            "point": self._point,
            "points": lambda _: [f"{k + 1}: {p.as_cli()}" for k, p in enumerate(self.points)] or ["no points yet"],
            "undo": self._undo,
            "calibration": lambda _: calibration_block(self.points),
            "save": self._save,
            "quit": self._quit,
            "exit": self._quit,
        }.get(command)
        if handler is not None:
            return handler(rest.strip())
        confirmed = text.endswith("!")
        raw = text[:-1].rstrip() if confirmed else text
        if not raw:
            return []
        refusal = None if confirmed else self._below_surface(raw)
        if refusal is not None:
            return [refusal]
        out = self._raw(raw)
        code = raw.split(None, 1)[0].upper()
        if code in ("G90", "G91"):
            self.relative = code == "G91"
        return out

    def _below_surface(self, raw: str) -> str | None:
        """The refusal of a typed G0/G1 whose Z ends below the known skin surface, else None. (Only jogs were
        guarded: `G1 Z0` typed over the skin went straight to the printer.)"""
        from neatskin.gcode.parse import GcodeSyntaxError, parse_line

        if self.surface_z_mm is None:
            return None
        try:
            line = parse_line(raw)
        except GcodeSyntaxError:
            return None  # the printer answers it
        z = None if line is None or line.code not in ("G0", "G1") else line.get("Z")
        if z is None:
            return None
        target = self.driver.position().z_mm + z if self.relative else z
        return self._surface_refusal(repr(raw), target, f"type {raw} ! to send it anyway")

    def _surface_refusal(self, what: str, target_z_mm: float, override: str) -> str | None:
        """The one refusal of a move (a z- jog or a typed G0/G1) whose Z ends below the known skin surface."""
        surface = self.surface_z_mm
        if surface is None or target_z_mm >= surface - 1e-9:
            return None
        return (
            f"refused: {what} would take the probe to Z {target_z_mm:.3f}, {surface - target_z_mm:.3f} mm below the "
            f"skin surface at Z {surface:.3f}; {override}"
        )

    # ---- commands ----

    @staticmethod
    def _help(arg: str) -> list[str]:
        sections = (__doc__ or "").split("\n\n")
        if arg == "ctrl-c":
            return sections[3].splitlines()
        return [*sections[2].splitlines(), "", "Ctrl-C halts motion: help ctrl-c says how"]

    def _raw(self, text: str) -> list[str]:
        replies = self.driver.send(text, strict=False)
        return [r for r in replies if r.strip()] + ["ok"]

    @property
    def surface_z_mm(self) -> float | None:
        """The skin surface this session knows of: the profile's, else the lowest calibration point's Z."""
        if self.profile_surface_z_mm is not None:
            return self.profile_surface_z_mm
        return min((p.printer_z_mm for p in self.points), default=None)

    def jog(self, axis: str, sign: str, amount: str | None, *, confirmed: bool = False) -> list[str]:
        step = float(amount) if amount else self.step_mm
        if not (math.isfinite(step) and 0 < step <= 100):
            return [f"jog step must be in (0, 100] mm, got {step}"]
        dist = step if sign == "+" else -step
        before: PositionLike | None = None
        if axis == "Z" and dist < 0:  # down: where it ends is checked against the surface and the printer's limit
            before = self.driver.position()
            refusal = self._surface_refusal(f"z- {step:g}", before.z_mm + dist, f"type z- {step:g}! to go there anyway")
            if refusal is not None and not confirmed:
                return [refusal]
        self.driver.send("G91")
        try:
            self.driver.send(f"G0 {axis}{dist:g} F{JOG_FEED_MM_MIN[axis]:g}")
        finally:  # a refused jog (beyond a soft limit) must not leave the printer in relative mode
            self.driver.send("G90")
        self.driver.send("M400")
        after = self.driver.position()
        out = [_fmt_position(after)]
        if before is not None and after.z_mm > before.z_mm + dist + 1e-3:
            out.append(
                f"the printer stopped at Z {after.z_mm:.3f}, not Z {before.z_mm + dist:.3f}: "
                "it clamped the move (a soft limit)"
            )
        return out

    def _step(self, arg: str) -> list[str]:
        try:
            value = float(arg)
        except ValueError:
            return [f"jog step is {self.step_mm:g} mm; set it with: step 0.1 | step 1 | step 10"]
        if not (math.isfinite(value) and 0 < value <= 100):
            return ["jog step must be in (0, 100] mm"]
        self.step_mm = value
        return [f"jog step {value:g} mm"]

    def _endstops(self, _: str) -> list[str]:
        states = self.driver.endstops()
        return [" ".join(f"{k}:{'TRIGGERED' if v else 'open'}" for k, v in states.items())]

    def _point(self, arg: str) -> list[str]:
        try:
            sx, sy = (float(v) for v in arg.replace(",", " ").split())
        except ValueError:
            return ["usage: point SX SY  (the sensor-frame mm of the mark the probe now touches, e.g. point 0 0)"]
        p = self.driver.position()
        point = ReferencePoint(sx, sy, p.x_mm, p.y_mm, p.z_mm)
        self.points.append(point)
        out = [f"point {len(self.points)}: sensor ({sx:g}, {sy:g}) = printer {_fmt_position(p)}"]
        if len(self.points) >= 2:
            try:
                out += calibration_block(self.points)[-2:-1]
            except ConfigError as exc:
                out.append(f"not yet a calibration: {exc}")
        else:
            out.append("jog to a second mark (far from the first) and confirm it with point SX SY")
        return out

    def _undo(self, _: str) -> list[str]:
        if not self.points:
            return ["no points to drop"]
        dropped = self.points.pop()
        return [f"dropped point {len(self.points) + 1}: {dropped.as_cli()}"]

    def _save(self, arg: str) -> list[str]:
        path = Path(arg) if arg else self.calibration_out
        if path is None:
            return ["usage: save FILE (or start the console with --calibration-out FILE)"]
        block = calibration_block(self.points)
        path.write_text("\n".join(block) + "\n", encoding="utf-8")
        return [f"wrote {path}: paste its [calibration] into the printer profile"]

    def _quit(self, _: str) -> list[str]:
        self.done = True
        return []

    # ---- Ctrl-C ----

    def halt(self) -> list[str]:
        """After Ctrl-C during a command: let the moves in flight finish (M400), lift Z, say where we are.
        A second Ctrl-C in here sends M112."""
        out = ["Ctrl-C: letting the move in flight finish (no M410 quickstop), then lifting the probe"]
        try:
            self.driver.send("M400")
            p = self.driver.position()
            target = p.z_mm + self.lift_mm
            surface = self.surface_z_mm
            if surface is not None:
                target = max(target, surface + self.lift_mm)  # never left in the skin: above its surface
            for command in ("G90", f"G0 Z{target:.3f} F{JOG_FEED_MM_MIN['Z']:g}", "M400"):
                self.driver.send(command)
            now = self.driver.position()
            if surface is not None and now.z_mm < surface:
                out.append(f"could not lift above the surface at Z {surface:.3f}: {_fmt_position(now)}")
            else:
                out.append(f"halted and lifted {target - p.z_mm:g} mm: {_fmt_position(now)}")
        except KeyboardInterrupt:
            self.driver.emergency_stop()
            out.append("second Ctrl-C: M112 sent (emergency stop); reset the printer and home it before moving")
            self.done = True
        return out


JOG_KEYS = {  # Alt + key (Esc then key on terminals without Alt): jog by the current step
    "right": "x+",
    "left": "x-",
    "up": "y+",
    "down": "y-",
    "pageup": "z+",
    "pagedown": "z-",
}


def jog_key_bindings():  # -> prompt_toolkit KeyBindings
    """Alt+arrows jog X/Y, Alt+PageUp/PageDown jog Z: the key ends the prompt with the jog command."""
    from prompt_toolkit.key_binding import KeyBindings

    bindings = KeyBindings()
    for key, command in JOG_KEYS.items():

        @bindings.add("escape", key)
        def _(event, command: str = command) -> None:
            event.app.exit(result=command)

    return bindings


def run_console(
    port: str,
    *,
    baud_rate: int = 115200,
    connect_timeout_s: float = 5.0,
    history_path: Path | None = None,
    calibration_out: Path | None = None,
    surface_z_mm: float | None = None,
) -> int:
    """The interactive shell: prompt_toolkit prompt with file history, the session's commands, Ctrl-C halts."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.history import FileHistory

    from neatskin.marlin.driver import MarlinDriver

    history = history_path or Path.home() / ".neatskin_console_history"
    driver = MarlinDriver.open(port, baud_rate)
    driver.connect(connect_timeout_s)
    session = ConsoleSession(driver, calibration_out=calibration_out, surface_z_mm=surface_z_mm)
    prompt: PromptSession[str] = PromptSession(history=FileHistory(str(history)), key_bindings=jog_key_bindings())
    print(f"connected to {driver.port_name}; `help` lists the commands, Ctrl-D or quit leaves")
    try:
        while not session.done:
            try:
                line = prompt.prompt(PROMPT)
            except KeyboardInterrupt:  # at the prompt: nothing is in flight, clear the line
                continue
            except EOFError:
                break
            try:
                out = session.handle(line)
            except KeyboardInterrupt:
                out = session.halt()
            except (NeatskinError, ValueError) as exc:
                out = [f"error: {exc}"]
            for text in out:
                print(text)
    finally:
        driver.close()
    return 0

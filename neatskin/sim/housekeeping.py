"""The simulated Marlin's commands a host sends around the motion: the temperature auto-report (M155), the
keep-alive interval (M113), the print job timer (M75-M77, M31) and the settings commands (M500-M503).

Each answers as the native stock build does (../shared/marlin; tests/test_marlin_real_vs_sim.py replays the same
bytes to both): `M155 S1` reports ` T:.. /.. B:.. /.. @:0 B@:0` every second, busy or idle, until `M155 S0`;
`M113` alone says `echo:M113 S2`, `M113 S0` silences the `busy: processing` keep-alives; M31 prints the print job
timer as Marlin's duration_t does (`1h 2m 3s`); M500 warns that there is no EEPROM, M501 and M502 load the
defaults (M501 reports them), M503 reports the settings (`S0`: the commands alone, without `echo:`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from neatskin.gcode.parse import GcodeLine

AMBIENT_C = 25.0  # the hot end and bed of a probe rig are never heated: the room's temperature
TEMPERATURES = f"T:{AMBIENT_C:.2f} /0.00 B:{AMBIENT_C:.2f} /0.00 @:0 B@:0"
CODES = frozenset({"M31", "M75", "M76", "M77", "M113", "M155", "M500", "M501", "M502", "M503"})


def duration_text(seconds: float) -> str:
    """Marlin's duration_t::toString: `0s`, `5m 3s`, `2h 0m 7s`, `1d 0h 0m 0s`, `1y 0d 0h 0m 0s`."""
    s = int(seconds)
    fields = (s // 31_536_000, s // 86_400 % 365, s // 3600 % 24, s // 60 % 60, s % 60)
    units = ("y", "d", "h", "m", "s")
    first = next((k for k, value in enumerate(fields) if value), 4)  # the largest unit not zero; seconds always
    return " ".join(f"{value}{unit}" for value, unit in zip(fields[first:], units[first:]))


class Housekeeping:
    """The state those commands keep; `emit` writes a reply line, `now` reads the firmware's clock."""

    def __init__(self, emit: Callable[[str], None], now: Callable[[], float], keepalive_s: float) -> None:
        self._emit = emit
        self._now = now
        self.keepalive_s = keepalive_s  # M113's interval; 0: no keep-alives
        self.report_every_s = 0.0  # M155's interval; 0: off
        self.next_report_s = math.inf
        self._timer_started_s: float | None = None  # the print job timer: running since, or paused/stopped
        self._timer_total_s = 0.0
        self._timer_stopped = True

    def run(self, code: str, line: GcodeLine | None, settings: Callable[[bool], list[str]]) -> None:
        """Run one of CODES; `settings(comments)` is the settings report's lines (M503's)."""
        s = line.get("S") if line is not None else None
        if code == "M155":
            if s is not None:
                self.report_every_s = min(max(s, 0.0), 60.0)  # Marlin keeps the interval in 0..60 s
                self.next_report_s = self._now() + self.report_every_s if self.report_every_s > 0 else math.inf
        elif code == "M113":
            if s is None:
                self._emit(f"echo:M113 S{self.keepalive_s:g}")
            else:
                self.keepalive_s = min(max(s, 0.0), 60.0)
        elif code in ("M75", "M76", "M77"):
            self._timer(code)
        elif code == "M31":
            self._emit(f"echo:Print time: {duration_text(self.timer_s())}")
        elif code == "M500":
            self._emit("Warning:EEPROM disabled")
        elif code in ("M501", "M502"):
            self._emit("echo:Hardcoded Default Settings Loaded")
            if code == "M501":
                for text in settings(True):
                    self._emit(text)
        elif code == "M503":
            for text in settings(s is None or s > 0):
                self._emit(text)

    def reports_due(self, until_s: float) -> None:
        """Write every temperature report due by until_s (M155)."""
        while self.next_report_s <= until_s:
            self._emit(" " + TEMPERATURES)
            self.next_report_s += self.report_every_s

    def timer_s(self) -> float:
        running = 0.0 if self._timer_started_s is None else self._now() - self._timer_started_s
        return self._timer_total_s + running

    def _timer(self, code: str) -> None:
        """Marlin's Stopwatch: M75 starts (from zero after a stop), M76 pauses, M77 stops (the time stays)."""
        now = self._now()
        if code == "M75":
            if self._timer_stopped:
                self._timer_total_s, self._timer_stopped = 0.0, False
            if self._timer_started_s is None:
                self._timer_started_s = now
            return
        if self._timer_started_s is not None:
            self._timer_total_s += now - self._timer_started_s
            self._timer_started_s = None
        if code == "M77":
            self._timer_stopped = True

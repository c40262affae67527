"""The simulated Marlin's editable settings (M92, M201, M203, M204, M205, M206, M301), the settings report they feed
(M503, M501, the boot banner), and how Marlin prints a float (32-bit, Print::printFloat's rounding).

Each command answers as the native stock build does (../shared/marlin; tests/marlin_replay.py's SETTINGS script
replays the same bytes to both): with a parameter it sets silently (`M206` then prints the position, as
M206.cpp's report_current_position), without one it prints its line of the report (`  M92 X80.00 Y80.00 ...`);
`M205 J` outside 0.01..0.3 answers `Error:?J out of range (0.01 to 0.3)` and keeps the old value; `M92 E` below
20 scales the E feed limit as M92.cpp does. M501 and M502 load the defaults (the profile's, as
protocols/printers/*.toml say). Values are kept as 32-bit floats, as the firmware keeps them.
The simulated motion keeps the profile's feeds and accelerations: these commands change what is reported, not
how fast the simulated head moves (docs/marlin.md, Known limits).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable

from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile

CODES = frozenset({"M92", "M201", "M203", "M204", "M205", "M206", "M301"})
STEPS_PER_MM = (80.0, 80.0, 400.0, 500.0)  # Marlin's stock DEFAULT_AXIS_STEPS_PER_UNIT, as the native build
_XYZE = "XYZE"
J_RANGE_ERROR = "Error:?J out of range (0.01 to 0.3)"


_FLOAT32 = struct.Struct("<f")


def f32(value: float, _pack=_FLOAT32.pack, _unpack=_FLOAT32.unpack) -> float:
    """The nearest 32-bit float (Marlin's `float`; the parser reads numbers with strtof)."""
    return _unpack(_pack(value))[0]


def marlin_float(value: float, digits: int = 2) -> str:
    """A float as Marlin prints it (serial_base.h printFloat on the float widened to double): the sign, then
    `digits` decimals after adding half of the last one and cutting, digit by digit. The float is 32-bit, so
    52.345 (52.34500122 as a float) prints 52.35 where a 64-bit %.2f prints 52.34."""
    number = f32(value)
    sign = ""
    if number < 0.0:
        sign, number = "-", -number
    rounding = 0.5
    for _ in range(digits):
        rounding *= 0.1
    number += rounding
    whole = int(number)
    remainder = number - whole
    out = [sign, str(whole)]
    if digits:
        out.append(".")
        for _ in range(digits):
            remainder *= 10.0
            digit = int(remainder)
            out.append(str(digit))
            remainder -= digit
    return "".join(out)


def lround32(mm: float, steps_per_mm: float) -> int:
    """Steps as the planner counts them: lroundf of the 32-bit product (half away from zero)."""
    product = f32(f32(mm) * f32(steps_per_mm))
    return int(math.copysign(math.floor(abs(product) + 0.5), product))


class Settings:
    """The values the settings commands edit, each a 32-bit float, from the profile's defaults."""

    def __init__(self, profile: PrinterProfile) -> None:
        self.profile = profile
        self.load_defaults()

    def load_defaults(self) -> None:
        """M502 (and M501 without EEPROM): the configuration's values."""
        p = self.profile
        fx, fy, fz = p.max_feed_mm_s
        ax, ay, az = p.max_accel_mm_s2
        a = f32(p.accel_mm_s2)
        self.steps_per_mm = [f32(v) for v in STEPS_PER_MM]
        self.max_feed_mm_s = [f32(v) for v in (fx, fy, fz, 25.0)]
        self.max_accel_mm_s2 = [f32(v) for v in (ax, ay, az, 10000.0)]
        self.accel_mm_s2 = [a, a, a]  # P (printing), R (retract), T (travel)
        self.advanced = [20000.0, 0.0, 0.0, f32(0.013)]  # B min segment us, S, T min feeds, J junction deviation
        self.home_offset_mm = [0.0, 0.0, 0.0]
        self.pid = [f32(22.2), f32(1.08), f32(114.0)]

    def run(self, code: str, line: GcodeLine | None, emit: Callable[[str], None]) -> bool:
        """Run one of CODES; True when it set a value (M206 then reports the position), False when it reported."""
        params = line.params if line is not None else {}
        values = {k: f32(v) for k, v in params.items() if isinstance(v, float)}
        if code == "M205":
            if not params:
                emit(self.report_line(code))
                return False
            if "B" in values:
                self.advanced[0] = float(int(values["B"]))  # value_ulong
            for i, key in ((1, "S"), (2, "T")):
                if key in values:
                    self.advanced[i] = values[key]
            if "J" in values:
                if f32(0.01) <= values["J"] <= f32(0.3):
                    self.advanced[3] = values["J"]
                else:
                    emit(J_RANGE_ERROR)
            return True
        seen = {"M92": "XYZE", "M201": "TXYZE", "M203": "TXYZE", "M204": "PRST", "M206": "XYZ", "M301": "PID"}[code]
        if not any(k in params for k in seen):
            emit(self.report_line(code))
            return False
        if code == "M204":
            if "S" in values:
                self.accel_mm_s2[0] = self.accel_mm_s2[2] = values["S"]
            for i, key in enumerate("PRT"):
                if key in values:
                    self.accel_mm_s2[i] = values[key]
        elif code == "M301":
            for i, key in enumerate("PID"):
                if key in values:
                    self.pid[i] = values[key]
        elif code == "M206":
            for i, key in enumerate("XYZ"):
                if key in values:
                    self.home_offset_mm[i] = values[key]
        else:
            table = {"M92": self.steps_per_mm, "M201": self.max_accel_mm_s2, "M203": self.max_feed_mm_s}[code]
            for i, key in enumerate(_XYZE):
                if key in values:
                    if code == "M92" and key == "E" and values["E"] < 20:  # M92.cpp: scales the E limits along
                        self.max_feed_mm_s[3] = f32(self.max_feed_mm_s[3] * f32(self.steps_per_mm[3] / values["E"]))
                    table[i] = values[key]
        return True

    def report_line(self, code: str) -> str:
        """The command's own line of the settings report, as `M92` alone prints it."""
        m = marlin_float
        if code in ("M92", "M201", "M203"):
            table = {"M92": self.steps_per_mm, "M201": self.max_accel_mm_s2, "M203": self.max_feed_mm_s}[code]
            return f"  {code} " + " ".join(f"{k}{m(v)}" for k, v in zip(_XYZE, table))
        if code == "M204":
            return "  M204 " + " ".join(f"{k}{m(v)}" for k, v in zip("PRT", self.accel_mm_s2))
        if code == "M205":
            return "  M205 " + " ".join(f"{k}{m(v)}" for k, v in zip("BSTJ", self.advanced))
        if code == "M206":
            return "  M206 " + " ".join(f"{k}{m(v)}" for k, v in zip("XYZ", self.home_offset_mm))
        return "  M301 " + " ".join(f"{k}{m(v)}" for k, v in zip("PID", self.pid))


_HEADINGS = (
    ("M92", "Steps per unit:"),
    ("M203", "Max feedrates (units/s):"),
    ("M201", "Max Acceleration (units/s2):"),
    ("M204", "Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):"),
    ("M205", "Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>):"),
    ("M206", "Home offset:"),
    ("M301", "Hotend PID:"),
)


def settings_report(settings: Settings, comments: bool) -> list[str]:
    """M503's report (MarlinSettings::report): with comments, each setting under its `; heading`, every line after
    `echo:`; without (M503 S0), the commands alone and no `echo:`."""
    sections = [
        ("Linear Units:", "  G21 ; (mm)"),
        ("Temperature Units:", "  M149 C ; Units in Celsius"),
        ("Filament settings (Disabled):", "  M200 S0 D1.75"),
        *((heading, settings.report_line(code)) for code, heading in _HEADINGS),
    ]
    if not comments:
        return [command for _, command in sections]
    return [line for heading, command in sections for line in (f"echo:; {heading}", f"echo:{command}")]

"""What the simulated Marlin prints that is fixed text: the start-up banner and settings report, and M115's report.

Both follow the real firmware (bugfix-2.1.x built natively, ../shared/marlin) line for line; the
numbers in the settings report come from the printer profile (feeds, accelerations, planner size),
the rest is Marlin's stock configuration. Only the version, build date and board line differ
from the real build (tests/test_marlin_real_vs_sim.py lists every exception).
"""

from __future__ import annotations

from neatskin.gcode.profile import PrinterProfile

VERSION = "2.1.2.4 (neatskin simulated printer)"
STEPS_PER_MM = (80.0, 80.0, 400.0, 500.0)  # Marlin's stock DEFAULT_AXIS_STEPS_PER_UNIT, as the native build

# Cap:... lines of the native build's M115 (EXTENDED_CAPABILITIES_REPORT), in its order; no Cap:ADVANCED_OK line
CAPABILITIES = (
    ("SERIAL_XON_XOFF", 0),
    ("BINARY_FILE_TRANSFER", 0),
    ("EEPROM", 0),
    ("VOLUMETRIC", 1),
    ("AUTOREPORT_POS", 0),
    ("AUTOREPORT_TEMP", 1),
    ("PROGRESS", 0),
    ("PRINT_JOB", 1),
    ("AUTOLEVEL", 0),
    ("RUNOUT", 0),
    ("Z_PROBE", 0),
    ("LEVELING_DATA", 0),
    ("BUILD_PERCENT", 0),
    ("SOFTWARE_POWER", 0),
    ("TOGGLE_LIGHTS", 0),
    ("CASE_LIGHT_BRIGHTNESS", 0),
    ("EMERGENCY_PARSER", 0),
    ("HOST_ACTION_COMMANDS", 0),
    ("PROMPT_SUPPORT", 0),
    ("SDCARD", 0),
    ("REPEAT", 0),
    ("SD_WRITE", 0),
    ("AUTOREPORT_SD_STATUS", 0),
    ("LONG_FILENAME", 0),
    ("LFN_WRITE", 0),
    ("CUSTOM_FIRMWARE_UPLOAD", 0),
    ("EXTENDED_M20", 0),
    ("THERMAL_PROTECTION", 1),
    ("MOTION_MODES", 0),
    ("ARCS", 1),
    ("BABYSTEPPING", 0),
    ("EP_BABYSTEP", 0),
    ("CHAMBER_TEMPERATURE", 0),
    ("COOLER_TEMPERATURE", 0),
    ("MEATPACK", 0),
    ("CONFIG_EXPORT", 0),
)


def m115_lines() -> list[str]:
    first = (
        f"FIRMWARE_NAME:Marlin {VERSION} SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
        "MACHINE_TYPE:NeatSkin rig KINEMATICS:Cartesian EXTRUDER_COUNT:1 UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff"
    )
    return [first] + [f"Cap:{name}:{value}" for name, value in CAPABILITIES]


def banner_lines(profile: PrinterProfile) -> list[str]:
    """`start` and what Marlin prints after it at boot: version, memory, the settings report (M503's)."""
    return [
        "start",
        "PowerUp",
        f"Marlin {VERSION}",
        "echo: Last Updated: 2024-07-30 | Author: (none, default config)",
        "echo: Compiled: neatskin",
        f"echo: Free Memory: 0  PlannerBufferBytes: {92 * profile.planner_buffer_size}",
        "echo:Hardcoded Default Settings Loaded",
        *settings_report(profile, comments=True),
    ]


def settings_report(profile: PrinterProfile, comments: bool) -> list[str]:
    """M503's report (MarlinSettings::report): with comments, each setting under its `; heading`, every line after
    `echo:`; without (M503 S0), the commands alone and no `echo:`."""
    fx, fy, fz = profile.max_feed_mm_s
    ax, ay, az = profile.max_accel_mm_s2
    a = profile.accel_mm_s2
    sx, sy, sz, se = STEPS_PER_MM
    sections = [
        ("Linear Units:", "G21 ; (mm)"),
        ("Temperature Units:", "M149 C ; Units in Celsius"),
        ("Filament settings (Disabled):", "M200 S0 D1.75"),
        ("Steps per unit:", f"M92 X{sx:.2f} Y{sy:.2f} Z{sz:.2f} E{se:.2f}"),
        ("Max feedrates (units/s):", f"M203 X{fx:.2f} Y{fy:.2f} Z{fz:.2f} E25.00"),
        ("Max Acceleration (units/s2):", f"M201 X{ax:.2f} Y{ay:.2f} Z{az:.2f} E10000.00"),
        (
            "Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):",
            f"M204 P{a:.2f} R{a:.2f} T{a:.2f}",
        ),
        (
            "Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>):",
            "M205 B20000.00 S0.00 T0.00 J0.01",
        ),
        ("Home offset:", "M206 X0.00 Y0.00 Z0.00"),
        ("Hotend PID:", "M301 P22.20 I1.08 D114.00"),
    ]
    if not comments:
        return [f"  {command}" for _, command in sections]
    return [line for heading, command in sections for line in (f"echo:; {heading}", f"echo:  {command}")]

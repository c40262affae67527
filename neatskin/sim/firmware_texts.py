"""What the simulated Marlin prints that is fixed text: the start-up banner and M115's report.

Both follow the real firmware (bugfix-2.1.x built natively, ../shared/marlin) line for line; the
settings report in the banner is sim.settings' (the profile's feeds and accelerations, the rest
Marlin's stock configuration). Only the version, build date and board line differ
from the real build (tests/test_marlin_real_vs_sim.py lists every exception).
"""

from __future__ import annotations

from neatskin.gcode.profile import PrinterProfile

VERSION = "2.1.2.4 (neatskin simulated printer)"

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


def banner_lines(profile: PrinterProfile, settings_report: list[str]) -> list[str]:
    """`start` and what Marlin prints after it at boot: version, memory, the settings report (M503's, with its
    comments: sim.settings)."""
    return [
        "start",
        "PowerUp",
        f"Marlin {VERSION}",
        "echo: Last Updated: 2024-07-30 | Author: (none, default config)",
        "echo: Compiled: neatskin",
        f"echo: Free Memory: 0  PlannerBufferBytes: {92 * profile.planner_buffer_size}",
        "echo:Hardcoded Default Settings Loaded",
        *settings_report,
    ]

"""The schemas of the campaign's own files: the protocol (and its caps), the skin layout and the mux wiring.

This module (with `printerfile`, the printer profile's, `studyfile`, the design study's, and
`scene`, the protocol's `[scene]` table's) is the one place where a file's keys and defaults are
declared; the loaders (`rig.protocol`, `layout`, `acquisition.wiring`, `gcode.profile`, `gcode.spec`)
parse with these schemas and then check what spans several keys; docs/config.md is generated from them
(`python -m neatskin.config.docs`). The `[scene]` table's keys are declared here; its presets' values
live with the simulation (`neatskin.sim.scene.PRESETS`), which fills in every knob left out.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from neatskin.config.declare import setting, source_field
from neatskin.config.scene import Scene
from neatskin.config.settings import Settings
from neatskin.errors import Problem

# ---- caps a run can execute (issue 10): anything beyond is refused by `campaign check` ------------
MAX_COUNT = 100_000  # distinct press positions
MAX_REPEATS = 10_000  # presses per position
MAX_PRESSES = 1_000_000  # positions x repeats: a press program held in memory
MAX_HOLD_S = 3_600.0  # one press held for an hour is already a creep experiment
MAX_RATE_HZ = 1_250_000.0  # the NI USB-6229's fastest AO/AI clock is below this
MAX_SAMPLES_PER_PRESS = 50_000_000  # 1.2 GB of float64 V, I, FSR in memory for one press
MAX_WAVEFORM_BYTES = 200 * 2**30  # 200 GiB of raw waveforms for a campaign
MAX_RIG_TIME_S = 14 * 86_400.0  # two weeks of rig time
MAX_NAME_LEN = 64
POSITION_STRATEGIES = ("paper", "grid", "stratified")
MAX_PATH_LEN = 1_024

SAFE_NAME = r"[A-Za-z0-9][A-Za-z0-9._-]*"
SAFE_NAME_TEXT = "a safe file name: ASCII letters, digits, '.', '_', '-', starting with a letter or digit"


def campaign_name_problems(name: str, source: str, where: str = "campaign.name") -> list[Problem]:
    """A campaign name becomes a folder name and G-code comment text: safe ASCII file-name characters only."""
    if re.fullmatch(SAFE_NAME, name) and len(name) <= MAX_NAME_LEN and name not in (".", ".."):
        return []
    injects = any(c in ";*(" or not c.isprintable() for c in name)
    why = "; its characters could inject G-code" if injects else ""
    bad = next((c for c in name if not c.isascii()), None)  # the one a technician cannot see comes first
    bad = bad or next((c for c in name if not re.fullmatch(r"[A-Za-z0-9._-]", c)), None)
    if bad is not None and not bad.isascii():
        why += f"; non-ASCII character {bad!r} (U+{ord(bad):04X})"
    elif bad is not None and bad.isprintable():
        why += f"; character {bad!r} is not allowed"
    return [
        Problem(
            f"campaign name {name!r} is not {SAFE_NAME_TEXT} (at most {MAX_NAME_LEN} characters){why}",
            source,
            where,
            'rename it, e.g. name = "paper-2019" (no spaces, slashes, accents or other non-ASCII characters)',
        )
    ]


# ---- protocol (protocols/*.toml) -------------------------------------------------------------------


@dataclass(frozen=True)
class CampaignTable(Settings):
    name: str = setting(max_len=MAX_NAME_LEN, doc="the campaign's name; " + SAFE_NAME_TEXT, example='"paper"')
    seed: int = setting(ge=0, doc="fixes positions, press order and the simulated noise", example="2019")
    description: str = setting("", allow_empty=True, doc="free text")


@dataclass(frozen=True)
class FilesTable(Settings):
    layout: str = setting(max_len=MAX_PATH_LEN, doc="skin layout TOML, relative to the protocol's folder")
    wiring: str = setting(max_len=MAX_PATH_LEN, doc="mux wiring TOML, relative to the protocol's folder")
    printer: str = setting(max_len=MAX_PATH_LEN, doc="printer profile TOML, relative to the protocol's folder")
    skin_profile: str | None = setting(
        None,
        max_len=MAX_PATH_LEN,
        default_doc="none: the layout's own channels",
        doc="skin profile TOML written by `neatskin skin fit`, relative to the protocol's folder: the dry run "
        "simulates that skin (its channel resistances and pinch)",
    )


@dataclass(frozen=True)
class PositionSpec(Settings):
    """Where the presses go (the strategies: neatskin.gcode.positions)."""

    TOML_TABLE = "positions"
    strategy: str = setting(choices=POSITION_STRATEGIES, doc="how positions are drawn", example='"paper"')
    count: int = setting(ge=1, le=MAX_COUNT, doc="distinct press positions", example="100")
    seed: int | None = setting(
        None, ge=0, default_doc="campaign.seed (0 built in Python)", doc="seed of the positions only"
    )
    min_spacing_mm: float = setting(0.0, unit="mm", ge=0, le=1_000, doc="between any two positions (0: off)")
    electrode_keep_out_mm: float = setting(0.0, unit="mm", ge=0, le=1_000, doc="radius kept clear of electrodes")
    keep_out: tuple[tuple[float, float, float], ...] = setting(
        (), unit="mm", ge=-1e5, le=1e5, doc="circles kept clear, each [x_mm, y_mm, radius_mm > 0]"
    )
    channel_fraction: float | None = setting(
        None, ge=0, le=1, default_doc="the channels' share of the pressable area", doc="share of positions on channels"
    )
    grid_shape: tuple[int, int] | None = setting(
        None, ge=1, le=MAX_COUNT, default_doc="square", doc="[rows, cols] of the grid strategy"
    )
    source: str = source_field()

    def cross_problems(self) -> list[tuple[str, str, str]]:
        problems = []
        for k, circle in enumerate(self.keep_out):
            if circle[2] <= 0:
                problems.append(
                    (
                        f"keep_out[{k}]",
                        f"keep-out zone {list(circle)!r} has no radius",
                        "write each zone as [x_mm, y_mm, radius_mm > 0]",
                    )
                )
        if self.strategy == "grid":
            rows, cols = self.grid_shape or square_grid(self.count)
            if rows * cols != self.count:
                problems.append(
                    (
                        "grid_shape",
                        f"a grid of {self.count} positions needs grid_shape rows x cols = count",
                        "give grid_shape = [rows, cols] with rows * cols = count, or a square count",
                    )
                )
        return problems


def square_grid(count: int) -> tuple[int, int]:
    """The square (rows, cols) of a grid of `count` positions, or (0, 0) when count is not a square."""
    side = math.isqrt(count)
    return (side, side) if side * side == count else (0, 0)


@dataclass(frozen=True)
class PressSpec(Settings):
    """How each position is pressed."""

    TOML_TABLE = "press"
    depth_mm: float = setting(unit="mm", ge=0, le=1_000, doc="below the skin's top surface", example="3.5")
    repeats: int = setting(ge=1, le=MAX_REPEATS, doc="presses per position", example="28")
    order: str = setting("position", choices=("position", "shuffled"), doc="repeats together, or shuffled")
    hold_s: float = setting(0.0, unit="s", ge=0, le=MAX_HOLD_S, doc="time at depth while the pairs are swept")
    probe_diameter_mm: float = setting(5.5, unit="mm", gt=0, le=100, doc="flat probe")
    travel_ordering: bool = setting(False, doc="order positions to shorten travel (order = 'position' only)")
    depth_margin_mm: float = setting(
        0.5, unit="mm", ge=0, le=100, doc="the probe stops at least this far above the skin's underside"
    )
    source: str = source_field()

    def cross_problems(self) -> list[tuple[str, str, str]]:
        if self.travel_ordering and self.order != "position":
            return [
                (
                    "travel_ordering",
                    "travel ordering only applies to order = 'position' (shuffled presses jump between positions on "
                    "purpose)",
                    "set travel_ordering = false or order = 'position'",
                )
            ]
        return []


@dataclass(frozen=True)
class Excitation(Settings):
    """The galvanostat's sine."""

    TOML_TABLE = "excitation"
    amplitude_a: float = setting(unit="A", gt=0, le=0.1, doc="peak excitation current", example="0.0005")
    frequency_hz: float = setting(unit="Hz", gt=0, le=MAX_RATE_HZ / 2, doc="excitation sine", example="1000.0")
    compliance_v: float = setting(
        50.0, unit="V", gt=0, le=1_000, doc="the galvanostat's output voltage limit (HA-151B class; set yours)"
    )
    press_margin: float = setting(
        1.5, ge=1, le=100, doc="largest pair R_eq under a press, as a multiple of the undeformed skin's"
    )


@dataclass(frozen=True)
class AcquisitionSettings(Settings):
    """The DAQ's clock and windows, and how a pair's resistance is demodulated."""

    TOML_TABLE = "acquisition"
    rate_hz: float = setting(unit="Hz", gt=0, le=MAX_RATE_HZ, doc="one sample clock for AO, AI, mux lines")
    settle_samples: int = setting(ge=0, le=1_000_000, doc="discarded after every mux switch")
    live_samples: int = setting(ge=2, le=10_000_000, doc="measured samples per pair and sweep")
    demodulation: str = setting(choices=("rms", "lockin"), doc="moving RMS and Ohm's law, or lock-in")
    window: int = setting(ge=2, le=10_000_000, doc="RMS window, samples (<= live_samples)")
    adc_range_v: float = setting(10.0, unit="V", gt=0, le=100, doc="AI input range (+-) of the voltage channel")
    voltage_gain: float = setting(0.5, gt=0, le=1_000, doc="AI volts per volt across the pair (monitor divider)")

    def cross_problems(self) -> list[tuple[str, str, str]]:
        if self.window > self.live_samples:
            return [
                (
                    "window",
                    f"window {self.window} is longer than the live window {self.live_samples}",
                    "set window <= live_samples",
                )
            ]
        return []


@dataclass(frozen=True)
class FsrTable(Settings):
    enabled: bool = setting(True, doc="a force-sensing resistor labels each press")
    pause_after_misses: int = setting(
        3,
        ge=0,
        le=10_000,
        doc="pause the campaign after this many presses in a row the FSR missed (0: never)",
    )


@dataclass(frozen=True)
class RecordTable(Settings):
    waveforms: bool = setting(False, doc="also store raw V, I, FSR samples (else per-press features only)")


@dataclass(frozen=True)
class ProtocolFile(Settings):
    """A campaign protocol (protocols/paper.toml)."""

    campaign: CampaignTable
    files: FilesTable
    positions: PositionSpec
    press: PressSpec
    excitation: Excitation
    acquisition: AcquisitionSettings
    fsr: FsrTable = FsrTable()
    record: RecordTable = RecordTable()
    scene: Scene = Scene()


# ---- skin layout (protocols/skins/*.toml) ------------------------------------------------------------


@dataclass(frozen=True)
class SkinTable(Settings):
    thickness_mm: float = setting(unit="mm", gt=0, le=1_000, doc="silicone skin thickness")
    channel_depth_mm: float = setting(unit="mm", gt=0, le=1_000, doc="channel centre line below the top surface")
    resistivity_ohm_m: float = setting(unit="ohm m", gt=0, le=1e9, doc="the fluid's resistivity")
    name: str | None = setting(None, max_len=200, default_doc="the file's stem", doc="layout name")
    description: str = setting("", allow_empty=True, doc="free text")


@dataclass(frozen=True)
class ChannelDefaultsTable(Settings):
    width_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="none", doc="every channel's")
    height_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="none", doc="every channel's")


@dataclass(frozen=True)
class JunctionEntry(Settings):
    name: str = setting(max_len=200, doc="unique name")
    x_mm: float = setting(unit="mm", ge=-1e5, le=1e5, doc="sensor frame")
    y_mm: float = setting(unit="mm", ge=-1e5, le=1e5, doc="sensor frame")


@dataclass(frozen=True)
class ChannelEntry(Settings):
    start: str = setting(key="from", doc="junction name")
    to: str = setting(doc="junction name")
    name: str | None = setting(None, max_len=200, default_doc="'<from>-<to>'", doc="channel name")
    length_mm: float | None = setting(None, unit="mm", gt=0, le=1e5, default_doc="straight distance", doc="length")
    width_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="channel_defaults", doc="width")
    height_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="channel_defaults", doc="height")


@dataclass(frozen=True)
class ElectrodeEntry(Settings):
    number: int = setting(ge=1, le=10_000, doc="electrode number (1, 2, ...)")
    junction: str = setting(doc="junction name it sits on")


@dataclass(frozen=True)
class LayoutFile(Settings):
    """A skin layout (protocols/skins/paper.toml)."""

    skin: SkinTable
    junctions: tuple[JunctionEntry, ...] = setting(min_items=1, doc="[[junctions]]")
    channels: tuple[ChannelEntry, ...] = setting(min_items=1, doc="[[channels]]")
    electrodes: tuple[ElectrodeEntry, ...] = setting(min_items=2, doc="[[electrodes]]")
    channel_defaults: ChannelDefaultsTable = ChannelDefaultsTable()


# ---- mux wiring (protocols/wiring/*.toml) -----------------------------------------------------------


@dataclass(frozen=True)
class LinesTable(Settings):
    A: str = setting(doc="address line A (bit 0), e.g. port0/line0")
    B: str = setting(doc="address line B (bit 1), e.g. port0/line1")


@dataclass(frozen=True)
class ChipEntry(Settings):
    inhibit: str = setting(doc="the chip's inhibit line, e.g. port0/line2")
    pins: dict[str, Any] = setting(doc="X0..X3, Y0..Y3 = electrode number (inline table)")
    name: str | None = setting(None, max_len=64, default_doc="'U<k>'", doc="as printed on the board")


@dataclass(frozen=True)
class ElectricalTable(Settings):
    """The mux chips' analog limits (MAX4052 class at +-8 V supplies; datasheet maxima, assumed)."""

    supply_positive_v: float = setting(8.0, unit="V", gt=0, le=100, doc="V+ rail: signals must stay below it")
    supply_negative_v: float = setting(-8.0, unit="V", ge=-100, lt=0, doc="V- rail: signals must stay above it")
    r_on_ohm: float = setting(100.0, unit="ohm", ge=0, le=1e5, doc="on-resistance of one switch (maximum)")
    r_on_mismatch_ohm: float = setting(10.0, unit="ohm", ge=0, le=1e5, doc="R_on difference between switches")


@dataclass(frozen=True)
class WiringFile(Settings):
    """A mux board (protocols/wiring/paper.toml)."""

    lines: LinesTable
    chips: tuple[ChipEntry, ...] = setting(min_items=1, doc="[[chips]], one per multiplexer")
    layout: str | None = setting(None, max_len=MAX_PATH_LEN, default_doc="none", doc="skin layout, relative")
    description: str = setting("", allow_empty=True, doc="free text")
    electrical: ElectricalTable = ElectricalTable()

"""The schema of every TOML file kind (protocol and its scene, layout, wiring, printer profile, study).

This module (with `studyfile`, the design study's, kept apart for its length) is the one place where
a file's keys and defaults are declared; the loaders
(`rig.protocol`, `layout`, `acquisition.wiring`, `gcode.profile`, `gcode.spec`) parse with these
schemas and then check what spans several keys; docs/config.md is generated from them
(`python -m neatskin.config.docs`). The `[scene]` table's keys are declared here; its presets' values
live with the simulation (`neatskin.sim.scene.PRESETS`), which fills in every knob left out.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any

from neatskin.config.schema import setting
from neatskin.config.studyfile import StudyFile
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
class CampaignTable:
    name: str = setting(max_len=MAX_NAME_LEN, doc="the campaign's name; " + SAFE_NAME_TEXT, example='"paper"')
    seed: int = setting(ge=0, doc="fixes positions, press order and the simulated noise", example="2019")
    description: str = setting("", allow_empty=True, doc="free text")


@dataclass(frozen=True)
class FilesTable:
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
class PositionsTable:
    strategy: str = setting(choices=("paper", "grid", "stratified"), doc="how positions are drawn")
    count: int = setting(ge=1, le=MAX_COUNT, doc="distinct press positions")
    seed: int | None = setting(None, ge=0, default_doc="campaign.seed", doc="seed of the positions only")
    min_spacing_mm: float = setting(0.0, unit="mm", ge=0, le=1_000, doc="between any two positions (0: off)")
    electrode_keep_out_mm: float = setting(0.0, unit="mm", ge=0, le=1_000, doc="radius kept clear of electrodes")
    keep_out: tuple[tuple[float, float, float], ...] = setting(
        (), unit="mm", doc="circles kept clear, each [x_mm, y_mm, radius_mm]"
    )
    channel_fraction: float | None = setting(
        None, ge=0, le=1, default_doc="the channels' share of the pressable area", doc="share of positions on channels"
    )
    grid_shape: tuple[int, int] | None = setting(
        None, ge=1, le=MAX_COUNT, default_doc="square", doc="[rows, cols] of the grid strategy"
    )


@dataclass(frozen=True)
class PressTable:
    depth_mm: float = setting(unit="mm", ge=0, le=1_000, doc="below the skin's top surface", example="3.5")
    repeats: int = setting(ge=1, le=MAX_REPEATS, doc="presses per position", example="28")
    order: str = setting("position", choices=("position", "shuffled"), doc="repeats together, or shuffled")
    hold_s: float = setting(0.0, unit="s", ge=0, le=MAX_HOLD_S, doc="time at depth while the pairs are swept")
    probe_diameter_mm: float = setting(5.5, unit="mm", gt=0, le=100, doc="flat probe")
    travel_ordering: bool = setting(False, doc="order positions to shorten travel (order = 'position' only)")
    depth_margin_mm: float = setting(
        0.5, unit="mm", ge=0, le=100, doc="the probe stops at least this far above the skin's underside"
    )


@dataclass(frozen=True)
class ExcitationTable:
    amplitude_a: float = setting(unit="A", gt=0, le=0.1, doc="peak excitation current", example="0.0005")
    frequency_hz: float = setting(unit="Hz", gt=0, le=MAX_RATE_HZ / 2, doc="excitation sine", example="1000.0")
    compliance_v: float = setting(
        50.0, unit="V", gt=0, le=1_000, doc="the galvanostat's output voltage limit (HA-151B class; set yours)"
    )
    press_margin: float = setting(
        1.5, ge=1, le=100, doc="largest pair R_eq under a press, as a multiple of the undeformed skin's"
    )


@dataclass(frozen=True)
class AcquisitionTable:
    rate_hz: float = setting(unit="Hz", gt=0, le=MAX_RATE_HZ, doc="one sample clock for AO, AI, mux lines")
    settle_samples: int = setting(ge=0, le=1_000_000, doc="discarded after every mux switch")
    live_samples: int = setting(ge=2, le=10_000_000, doc="measured samples per pair and sweep")
    demodulation: str = setting(choices=("rms", "lockin"), doc="moving RMS and Ohm's law, or lock-in")
    window: int = setting(ge=2, le=10_000_000, doc="RMS window, samples (<= live_samples)")
    adc_range_v: float = setting(10.0, unit="V", gt=0, le=100, doc="AI input range (+-) of the voltage channel")
    voltage_gain: float = setting(0.5, gt=0, le=1_000, doc="AI volts per volt across the pair (monitor divider)")


@dataclass(frozen=True)
class FsrTable:
    enabled: bool = setting(True, doc="a force-sensing resistor labels each press")
    pause_after_misses: int = setting(
        3,
        ge=0,
        le=10_000,
        doc="pause the campaign after this many presses in a row the FSR missed (0: never)",
    )


@dataclass(frozen=True)
class RecordTable:
    waveforms: bool = setting(False, doc="also store raw V, I, FSR samples (else per-press features only)")


# ---- the protocol's [scene]: what a dry run simulates (values of the presets: neatskin.sim.scene) ------

SCENE_PRESETS = ("ideal", "paper-like")
FROM_PRESET = "from `preset`"


def _knob(unit: str, doc: str, *, signed: bool = False, upper: float | None = None) -> Any:
    """A variability knob: None in the schema means "the preset's value" (neatskin.sim.scene.PRESETS)."""
    return setting(None, unit=unit, ge=None if signed else 0, le=upper, default_doc=FROM_PRESET, doc=doc)


@dataclass(frozen=True)
class SceneTable:
    """What a dry run simulates: the skin model's fidelity, the signal level and the rig effects. A preset sets
    every knob after `surface_error_mm` at once (`ideal`: all off; `paper-like`: fitted to the paper's error, see
    docs/skin.md); a knob written in the table overrides the preset's value. Every source is off at 0."""

    fidelity: str = setting(
        "deformation", choices=("deformation", "network"), doc="skin model: the deformation integral, or the network"
    )
    signal: str = setting(
        "features", choices=("features", "waveforms"), doc="simulate per-press features only, or raw waveforms"
    )
    noise: bool = setting(True, doc="measurement noise")
    preset: str = setting("ideal", choices=SCENE_PRESETS, doc="sets every knob left out of the table")
    surface_error_mm: float = setting(
        0.0, unit="mm", doc="the real skin surface lies this far below the calibrated one (within the skin)"
    )
    placement_error_mm: float | None = _knob("mm", "std of the press position, per press (at most 100 mm)")
    depth_jitter_mm: float | None = _knob("mm", "std of the press depth, per press (printer z, skin height)")
    fabrication_spread_fraction: float | None = _knob(
        "", "std of log(channel height), per channel, once per skin", upper=1.0
    )
    displaced_fluid_fraction: float | None = _knob(
        "", "share of the displaced fluid the sealed channels keep", upper=1.0
    )
    temperature_drift_k_per_h: float | None = _knob(
        "K/h", "fluid temperature ramp (negative: a cooling room)", signed=True
    )
    evaporation_fraction_per_h: float | None = _knob("1/h", "water lost through the silicone, per hour", upper=0.5)
    press_interval_s: float | None = _knob(
        "s", "campaign time between presses for drift and relaxation (0: the G-code's)"
    )
    hysteresis_fraction: float | None = _knob(
        "", "dent kept right after the lift, as a share of the press depth", upper=0.99
    )
    relaxation_time_s: float | None = _knob("s", "viscoelastic relaxation time of that dent")
    double_layer_capacitance_uf: float | None = _knob("uF", "per electrode, in series (0: no double layer)")
    adc_skew_us: float | None = _knob("us", "the current is sampled this long after the voltage (multiplexed ADC)")
    mains_pickup_mv: float | None = _knob("mV", "amplitude of the mains hum on the voltage channel")
    mains_frequency_hz: float | None = _knob("Hz", "mains frequency of that hum")


SCENE_KNOBS = tuple(f.name for f in dataclasses.fields(SceneTable) if f.default is None)
"""The variability knobs: what a preset sets."""


@dataclass(frozen=True)
class ProtocolFile:
    """A campaign protocol (protocols/paper.toml)."""

    campaign: CampaignTable
    files: FilesTable
    positions: PositionsTable
    press: PressTable
    excitation: ExcitationTable
    acquisition: AcquisitionTable
    fsr: FsrTable = FsrTable()
    record: RecordTable = RecordTable()
    scene: SceneTable = SceneTable()


# ---- skin layout (protocols/skins/*.toml) ------------------------------------------------------------


@dataclass(frozen=True)
class SkinTable:
    thickness_mm: float = setting(unit="mm", gt=0, le=1_000, doc="silicone skin thickness")
    channel_depth_mm: float = setting(unit="mm", gt=0, le=1_000, doc="channel centre line below the top surface")
    resistivity_ohm_m: float = setting(unit="ohm m", gt=0, le=1e9, doc="the fluid's resistivity")
    name: str | None = setting(None, max_len=200, default_doc="the file's stem", doc="layout name")
    description: str = setting("", allow_empty=True, doc="free text")


@dataclass(frozen=True)
class ChannelDefaultsTable:
    width_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="none", doc="every channel's")
    height_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="none", doc="every channel's")


@dataclass(frozen=True)
class JunctionEntry:
    name: str = setting(max_len=200, doc="unique name")
    x_mm: float = setting(unit="mm", ge=-1e5, le=1e5, doc="sensor frame")
    y_mm: float = setting(unit="mm", ge=-1e5, le=1e5, doc="sensor frame")


@dataclass(frozen=True)
class ChannelEntry:
    start: str = setting(key="from", doc="junction name")
    to: str = setting(doc="junction name")
    name: str | None = setting(None, max_len=200, default_doc="'<from>-<to>'", doc="channel name")
    length_mm: float | None = setting(None, unit="mm", gt=0, le=1e5, default_doc="straight distance", doc="length")
    width_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="channel_defaults", doc="width")
    height_mm: float | None = setting(None, unit="mm", gt=0, le=1_000, default_doc="channel_defaults", doc="height")


@dataclass(frozen=True)
class ElectrodeEntry:
    number: int = setting(ge=1, le=10_000, doc="electrode number (1, 2, ...)")
    junction: str = setting(doc="junction name it sits on")


@dataclass(frozen=True)
class LayoutFile:
    """A skin layout (protocols/skins/paper.toml)."""

    skin: SkinTable
    junctions: tuple[JunctionEntry, ...] = setting(min_items=1, doc="[[junctions]]")
    channels: tuple[ChannelEntry, ...] = setting(min_items=1, doc="[[channels]]")
    electrodes: tuple[ElectrodeEntry, ...] = setting(min_items=2, doc="[[electrodes]]")
    channel_defaults: ChannelDefaultsTable = ChannelDefaultsTable()


# ---- mux wiring (protocols/wiring/*.toml) -----------------------------------------------------------


@dataclass(frozen=True)
class LinesTable:
    A: str = setting(doc="address line A (bit 0), e.g. port0/line0")
    B: str = setting(doc="address line B (bit 1), e.g. port0/line1")


@dataclass(frozen=True)
class ChipEntry:
    inhibit: str = setting(doc="the chip's inhibit line, e.g. port0/line2")
    pins: dict[str, Any] = setting(doc="X0..X3, Y0..Y3 = electrode number (inline table)")
    name: str | None = setting(None, max_len=64, default_doc="'U<k>'", doc="as printed on the board")


@dataclass(frozen=True)
class ElectricalTable:
    """The mux chips' analog limits (MAX4052 class at +-8 V supplies; datasheet maxima, assumed)."""

    supply_positive_v: float = setting(8.0, unit="V", gt=0, le=100, doc="V+ rail: signals must stay below it")
    supply_negative_v: float = setting(-8.0, unit="V", ge=-100, lt=0, doc="V- rail: signals must stay above it")
    r_on_ohm: float = setting(100.0, unit="ohm", ge=0, le=1e5, doc="on-resistance of one switch (maximum)")
    r_on_mismatch_ohm: float = setting(10.0, unit="ohm", ge=0, le=1e5, doc="R_on difference between switches")


@dataclass(frozen=True)
class WiringFile:
    """A mux board (protocols/wiring/paper.toml)."""

    lines: LinesTable
    chips: tuple[ChipEntry, ...] = setting(min_items=1, doc="[[chips]], one per multiplexer")
    layout: str | None = setting(None, max_len=MAX_PATH_LEN, default_doc="none", doc="skin layout, relative")
    description: str = setting("", allow_empty=True, doc="free text")
    electrical: ElectricalTable = ElectricalTable()


# ---- printer profile (protocols/printers/*.toml) ------------------------------------------------------


@dataclass(frozen=True)
class PrinterTable:
    name: str | None = setting(None, max_len=200, default_doc="the file's stem", doc="printer name")
    description: str = setting("", allow_empty=True, doc="free text")
    firmware: str = setting("Marlin", max_len=64, doc="firmware family")
    baud_rate: int = setting(115_200, gt=0, le=10_000_000, doc="serial speed")
    planner_buffer_size: int = setting(16, gt=0, le=10_000, doc="BLOCK_BUFFER_SIZE: moves queued ahead")
    rx_buffer_size: int = setting(128, gt=0, le=1_000_000, doc="RX_BUFFER_SIZE: bytes of serial input")
    homing_time_s: float = setting(20.0, unit="s", gt=0, le=3_600, doc="G28 of all axes, worst case")
    stepper_timeout_s: float = setting(
        120.0,
        unit="s",
        ge=0,
        le=86_400,
        doc="DEFAULT_STEPPER_DEACTIVE_TIME: idle steppers go off after this (0: never); a longer pause re-homes",
    )


@dataclass(frozen=True)
class BedTable:
    size_x_mm: float = setting(unit="mm", gt=0, le=10_000, doc="bed size")
    size_y_mm: float = setting(unit="mm", gt=0, le=10_000, doc="bed size")


@dataclass(frozen=True)
class SoftLimitsTable:
    min_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    min_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    min_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")
    max_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="M211 soft limit")


@dataclass(frozen=True)
class MaxFeedTable:
    x_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")
    y_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")
    z_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="DEFAULT_MAX_FEEDRATE")


@dataclass(frozen=True)
class MaxAccelTable:
    x_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")
    y_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")
    z_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="DEFAULT_MAX_ACCELERATION")


@dataclass(frozen=True)
class MotionTable:
    accel_mm_s2: float = setting(unit="mm/s^2", gt=0, le=1e6, doc="M204 acceleration")
    travel_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="xy travel at the safe height")
    z_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="lifting and descending to contact")
    press_feed_mm_s: float = setting(unit="mm/s", gt=0, le=10_000, doc="from contact on to the press depth")
    safe_height_mm: float = setting(unit="mm", gt=0, le=10_000, doc="probe tip above the skin while travelling")


@dataclass(frozen=True)
class ParkTable:
    x_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.min_x_mm",
        doc="where the probe waits after the campaign, printer frame",
    )
    y_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.max_y_mm",
        doc="where the probe waits after the campaign, printer frame",
    )
    z_mm: float | None = setting(
        None,
        unit="mm",
        ge=-10_000,
        le=10_000,
        default_doc="soft_limits.max_z_mm",
        doc="where the probe waits after the campaign, printer frame",
    )


@dataclass(frozen=True)
class CalibrationTable:
    offset_x_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer xy of the sensor's origin")
    offset_y_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer xy of the sensor's origin")
    rotation_deg: float = setting(
        unit="deg", ge=-360, le=360, doc="sensor frame against the printer's, in degrees (a radian value is refused)"
    )
    surface_z_mm: float = setting(unit="mm", ge=-10_000, le=10_000, doc="printer z touching the skin surface")


@dataclass(frozen=True)
class PrinterFile:
    """A printer profile (protocols/printers/paper.toml)."""

    printer: PrinterTable
    bed: BedTable
    soft_limits: SoftLimitsTable
    max_feed: MaxFeedTable
    max_accel: MaxAccelTable
    motion: MotionTable
    calibration: CalibrationTable
    park: ParkTable = ParkTable()


FILE_KINDS: dict[str, type] = {
    "protocol": ProtocolFile,
    "layout": LayoutFile,
    "wiring": WiringFile,
    "printer profile": PrinterFile,
    "design study": StudyFile,
}

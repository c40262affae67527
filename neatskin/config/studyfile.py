"""The schema of a design study TOML (protocols/studies/*.toml): its tables, keys, units, ranges and defaults.

`neatskin.design.study` parses a study with this schema, then checks what spans several keys
(electrode counts against the smallest grid, explicit placements on the grid's junctions, press
depths inside the skin) and builds its `Study`. A sweep (a list of values) may be written as its
one value: `pitch_mm = 15.0` is `pitch_mm = [15.0]`.
"""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.config.declare import setting
from neatskin.config.settings import Settings

STUDY_STRATEGIES = ("boundary", "interior", "every_k", "explicit", "optimised")
STUDY_SCENES = ("ideal", "paper-like")
# a study's name becomes a folder name (out/design/<name>): no separator, no "..", no control character
STUDY_NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9._-]*"


@dataclass(frozen=True)
class StudyTable(Settings):
    name: str | None = setting(
        None,
        max_len=100,
        pattern=STUDY_NAME_PATTERN,
        pattern_text="a name (letters, digits, '.', '_' and '-', starting with a letter or digit; never a path)",
        default_doc="the file's stem",
        doc="the study's name; the default output folder is out/design/<name>",
    )
    seed: int = setting(0, ge=0, doc="fixes the optimiser's restarts and the simulated datasets")
    description: str = setting("", allow_empty=True, doc="free text")
    scene: str = setting("ideal", choices=STUDY_SCENES, doc="the skin simulated ('paper-like' is not available yet)")
    fidelity: str = setting(
        "deformation", choices=("deformation", "network"), doc="skin model: the deformation integral, or the network"
    )
    criterion: str = setting(
        "D", choices=("D", "A"), doc="the placement criterion: D, -mean log det F; A, mean trace F^-1 (mm^2)"
    )
    press_grid: int = setting(25, ge=4, le=10_000, doc="presses per side of the square press grid")


@dataclass(frozen=True)
class LayoutsTable(Settings):
    """The grid layouts swept: every size x pitch x channel width x channel height."""

    sizes: tuple[tuple[int, int], ...] = setting(
        ((3, 3),), ge=2, le=10_000, min_items=1, doc="[N, M] junctions of each grid", example="[[5, 5], [10, 10]]"
    )
    pitch_mm: tuple[float, ...] = setting(
        (15.0,), unit="mm", ge=0.5, le=1_000, min_items=1, one_or_list=True, doc="swept"
    )
    channel_width_mm: tuple[float, ...] = setting(
        (2.0,), unit="mm", ge=0.01, le=100, min_items=1, one_or_list=True, doc="swept"
    )
    channel_height_mm: tuple[float, ...] = setting(
        (1.0,), unit="mm", ge=0.01, le=100, min_items=1, one_or_list=True, doc="swept"
    )
    channel_depth_mm: float = setting(2.0, unit="mm", gt=0, le=1_000, doc="channel centre line below the top surface")
    thickness_mm: float = setting(5.5, unit="mm", ge=0.1, le=1_000, doc="silicone skin thickness")
    resistivity_ohm_m: float = setting(0.5, unit="ohm m", ge=1e-9, le=1e9, doc="the fluid's resistivity")


@dataclass(frozen=True)
class ExplicitEntry(Settings):
    junctions_mm: tuple[tuple[float, float], ...] = setting(
        unit="mm",
        min_items=2,
        doc="[x_mm, y_mm] of each electrode, from the bottom-left junction",
        example="[[0, 0], [15, 0]]",
    )
    name: str | None = setting(
        None,
        max_len=100,
        pattern=STUDY_NAME_PATTERN,
        pattern_text="a name (letters, digits, '.', '_' and '-', starting with a letter or digit; never a path)",
        default_doc="'explicit<k>'",
        doc="the placement's name (part of each candidate's file names)",
    )


@dataclass(frozen=True)
class ElectrodesTable(Settings):
    """The electrode counts and placement strategies swept."""

    counts: tuple[int, ...] = setting((8,), ge=2, le=10_000, min_items=1, one_or_list=True, doc="swept")
    strategies: tuple[str, ...] = setting(
        ("boundary",), choices=STUDY_STRATEGIES, min_items=1, one_or_list=True, doc="swept"
    )
    every_k: int = setting(2, ge=1, le=10_000, doc="the every_k strategy's step, in junctions")
    restarts: int = setting(8, ge=0, le=10_000, doc="random restarts of the optimised strategy")
    explicit: tuple[ExplicitEntry, ...] = setting((), doc="[[electrodes.explicit]], for the explicit strategy")


@dataclass(frozen=True)
class ProbesTable(Settings):
    diameter_mm: tuple[float, ...] = setting(
        (5.5,), unit="mm", ge=0.1, le=1_000, min_items=1, one_or_list=True, doc="swept"
    )
    depth_mm: tuple[float, ...] = setting(
        (3.5,), unit="mm", gt=0, le=1_000, min_items=1, one_or_list=True, doc="swept; below the top surface"
    )


@dataclass(frozen=True)
class StudyExcitationTable(Settings):
    amplitude_a: float = setting(
        0.0002, unit="A", gt=0, doc="peak excitation current (the paper's 2 mA exceeds the mux rails: docs/design.md)"
    )
    rails_v: float = setting(8.0, unit="V", gt=0, doc="the mux supply rails (+-): the signal must stay within")
    # the rest as a protocol's [excitation] and its wiring's [electrical] (same defaults, a test holds them equal):
    # the study runs the protocol's own electrical check on each candidate skin
    r_on_ohm: float = setting(100.0, unit="ohm", ge=0, le=1e5, doc="assumed mux on-resistance of one switch")
    r_on_mismatch_ohm: float = setting(10.0, unit="ohm", ge=0, le=1e5, doc="assumed R_on difference of switches")
    compliance_v: float = setting(50.0, unit="V", gt=0, le=1_000, doc="the galvanostat's output voltage limit")
    press_margin: float = setting(
        1.5, ge=1, le=100, doc="largest pair R_eq under a press, as a multiple of the undeformed skin's"
    )


@dataclass(frozen=True)
class StudyAcquisitionTable(Settings):
    rate_hz: float = setting(10_000.0, unit="Hz", gt=0, doc="sample clock")
    settle_samples: int = setting(20, ge=0, doc="discarded after every mux switch")
    live_samples: int = setting(100, ge=1, doc="measured samples per pair and sweep")
    break_samples: int = setting(2, ge=2, doc="break-before-make samples per switch")
    adc_range_v: float = setting(10.0, unit="V", gt=0, le=100, doc="AI input range (+-) of the voltage channel")
    voltage_gain: float = setting(0.5, gt=0, le=1_000, doc="AI volts per volt across the pair (monitor divider)")


@dataclass(frozen=True)
class NoiseTable(Settings):
    model: str = setting("lockin", choices=("lockin", "fixed"), doc="the simulated DAQ's noise, or a fixed std")
    std_ohm: float = setting(1.0, unit="ohm", gt=0, doc="the fixed model's std of R")
    voltage_noise_v: float = setting(2e-3, unit="V", ge=0, doc="white noise on the voltage channel (assumed)")
    current_noise_a: float = setting(1e-7, unit="A", ge=0, doc="white noise on the current channel (assumed)")
    quantise: bool = setting(True, doc="16-bit ADC quantisation")
    sweeps_per_press: int = setting(1, ge=1, doc="sweeps averaged per press")


@dataclass(frozen=True)
class LearnedTable(Settings):
    """A learned error from a simulated features-only dataset: positions x repeats, grouped split by position."""

    enabled: bool = setting(False, doc="estimate the learned error")
    positions: int = setting(120, ge=8, le=1_000_000, doc="distinct press positions")
    repeats: int = setting(4, ge=1, le=10_000, doc="presses per position")
    seeds: int = setting(3, ge=1, le=1_000, doc="datasets simulated; the error is reported with its spread")
    test_share: float = setting(0.25, ge=0.05, le=0.8, doc="share of positions held out")
    model: str = setting("knn", choices=("knn", "extra_trees"), doc="the learner")


@dataclass(frozen=True)
class InversionTable(Settings):
    """Locate each press of the map with the skin model itself."""

    enabled: bool = setting(False, doc="run the model inversion")
    draws: int = setting(2, ge=1, doc="noise draws per press")
    library: int = setting(40, ge=4, doc="search positions per side")
    depth_offsets_mm: tuple[float, ...] = setting(
        (-0.5, 0.0, 0.5), unit="mm", min_items=1, one_or_list=True, doc="depths searched, around the press depth"
    )
    iterations: int = setting(6, ge=0, doc="Gauss-Newton iterations")
    starts: int = setting(3, ge=1, doc="best library matches refined")


@dataclass(frozen=True)
class StudyFile(Settings):
    """A design study (protocols/studies/grid5.toml); every table is optional, lists are the values swept."""

    study: StudyTable = StudyTable()
    layouts: LayoutsTable = LayoutsTable()
    electrodes: ElectrodesTable = ElectrodesTable()
    probes: ProbesTable = ProbesTable()
    excitation: StudyExcitationTable = StudyExcitationTable()
    acquisition: StudyAcquisitionTable = StudyAcquisitionTable()
    noise: NoiseTable = NoiseTable()
    learned: LearnedTable = LearnedTable()
    inversion: InversionTable = InversionTable()

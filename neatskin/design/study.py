"""The design study file: what a study TOML may say, its validation (every problem at once, naming the file, the
field and the fix), and the Study value it becomes. Expanding a study into candidates lives in `candidates.py`.

A study names a family of grid layouts (sizes N x M, pitch, channel cross-section), electrode counts and placement
strategies, probes (diameter, depth), the excitation and acquisition timing, the noise model, the scene and
optionally a learned-error estimate. protocols/studies/grid5.toml is the worked example; docs/design.md the guide.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neatskin.config import TableReader
from neatskin.design import fields
from neatskin.design.fields import ExplicitPlacement
from neatskin.design.inversion import InversionSpec
from neatskin.errors import ConfigError, Problem
from neatskin.tomlfile import read_toml, resolve_path

STRATEGIES = ("boundary", "interior", "every_k", "explicit", "optimised")
SCENES = ("ideal", "paper-like")
FIDELITIES = ("deformation", "network")
NOISE_MODELS = ("lockin", "fixed")
CRITERIA = ("D", "A")
LEARNED_MODELS = ("knn", "extra_trees")
TOP_TABLES = (
    "study",
    "layouts",
    "electrodes",
    "probes",
    "excitation",
    "acquisition",
    "noise",
    "learned",
    "inversion",
)


@dataclass(frozen=True)
class LearnedSpec:
    """A learned error from a simulated features-only dataset: positions x repeats, grouped split by position."""

    enabled: bool = False
    positions: int = 120
    repeats: int = 4
    seeds: int = 3
    test_share: float = 0.25
    model: str = "knn"


@dataclass(frozen=True)
class Study:
    """A validated design study (see the module docstring); lists are the values swept."""

    name: str
    source: str
    seed: int = 0
    description: str = ""
    scene: str = "ideal"
    fidelity: str = "deformation"
    criterion: str = "D"
    press_grid: int = 25
    sizes: tuple[tuple[int, int], ...] = ((3, 3),)
    pitch_mm: tuple[float, ...] = (15.0,)
    channel_width_mm: tuple[float, ...] = (2.0,)
    channel_height_mm: tuple[float, ...] = (1.0,)
    channel_depth_mm: float = 2.0
    thickness_mm: float = 5.5
    resistivity_ohm_m: float = 0.5
    counts: tuple[int, ...] = (8,)
    strategies: tuple[str, ...] = ("boundary",)
    every_k: int = 2
    restarts: int = 8
    explicit: tuple[ExplicitPlacement, ...] = ()
    probe_diameter_mm: tuple[float, ...] = (5.5,)
    depth_mm: tuple[float, ...] = (3.5,)
    amplitude_a: float = 0.002
    rails_v: float = 8.0
    rate_hz: float = 10_000.0
    settle_samples: int = 20
    live_samples: int = 100
    break_samples: int = 2
    noise_model: str = "lockin"
    noise_std_ohm: float = 1.0
    voltage_noise_v: float = 2e-3
    current_noise_a: float = 1e-7
    quantise: bool = True
    sweeps_per_press: int = 1
    learned: LearnedSpec = field(default_factory=LearnedSpec)
    inversion: InversionSpec = field(default_factory=InversionSpec)


def load_study(path: str | Path) -> Study:
    """Read and validate a study TOML; one ConfigError listing every problem (file, field, fix)."""
    path = resolve_path(path)
    return study_from_dict(read_toml(path, "study file"), source=str(path))


def study_from_dict(data: dict[str, Any], source: str = "<memory>") -> Study:
    problems: list[Problem] = []
    for key in data:
        if key not in TOP_TABLES:
            close = difflib.get_close_matches(key, TOP_TABLES, n=1)
            fix = f"did you mean '{close[0]}'?" if close else f"remove it; known tables: {', '.join(TOP_TABLES)}"
            problems.append(Problem(f"unknown table [{key}]", source, key, fix))

    def table(name: str) -> TableReader:
        raw = data.get(name, {})
        if not isinstance(raw, dict):
            problems.append(Problem(f"[{name}] must be a table", source, name, f"write it as [{name}]"))
            raw = {}
        return TableReader(raw, name, source, problems)

    st = table("study")
    name = st.text("name", Path(source).stem if source != "<memory>" else "study")
    seed = st.integer("seed", 0, minimum=0)
    description = st._get("description", "")
    scene = st.choice("scene", SCENES, "ideal")
    fidelity = st.choice("fidelity", FIDELITIES, "deformation")
    crit = st.choice("criterion", CRITERIA, "D")
    press_grid = st.integer("press_grid", 25, minimum=4)
    st.check_unknown()
    if scene == "paper-like":
        problems.append(
            Problem(
                "scene 'paper-like' is not available yet (the variable paper-like skin is being added to skin/)",
                source,
                "study.scene",
                'use scene = "ideal" for now',
            )
        )

    lay = table("layouts")
    sizes = fields.sizes(lay, problems, source)
    pitch = fields.numbers(lay, "pitch_mm", [15.0], problems, source)
    width = fields.numbers(lay, "channel_width_mm", [2.0], problems, source)
    height = fields.numbers(lay, "channel_height_mm", [1.0], problems, source)
    channel_depth = lay.number("channel_depth_mm", 2.0, positive=True, unit="mm")
    thickness = lay.number("thickness_mm", 5.5, positive=True, unit="mm")
    resistivity = lay.number("resistivity_ohm_m", 0.5, positive=True, unit="ohm m")
    lay.check_unknown()
    if channel_depth is not None and thickness is not None and channel_depth >= thickness:
        problems.append(
            Problem(
                f"channel_depth_mm = {channel_depth} is not inside the {thickness} mm skin",
                source,
                "layouts.channel_depth_mm",
                "set channel_depth_mm below thickness_mm",
            )
        )

    el = table("electrodes")
    counts = fields.integers(el, "counts", [8], problems, source, minimum=2)
    strategies = fields.choices(el, "strategies", STRATEGIES, ["boundary"], problems, source)
    every_k = el.integer("every_k", 2, minimum=1)
    restarts = el.integer("restarts", 8, minimum=0)
    explicit = fields.explicit(el, problems, source)
    el.check_unknown()
    if "explicit" in strategies and not explicit:
        problems.append(
            Problem(
                "strategy 'explicit' needs at least one [[electrodes.explicit]] placement",
                source,
                "electrodes.strategies",
                "add [[electrodes.explicit]] with name and junctions_mm, or drop 'explicit'",
            )
        )
    if sizes and counts:
        smallest = min(sizes, key=lambda s: s[0] * s[1])
        for k, count in enumerate(counts):
            if count > smallest[0] * smallest[1]:
                problems.append(
                    Problem(
                        f"{count} electrodes but the {smallest[0]} x {smallest[1]} grid has only "
                        f"{smallest[0] * smallest[1]} junctions (one electrode per junction)",
                        source,
                        f"electrodes.counts[{k}]",
                        f"use at most {smallest[0] * smallest[1]} electrodes, or larger grids",
                    )
                )
    if sizes and pitch:
        fields.check_explicit_on_grid(explicit, sizes, pitch, problems, source)

    pr = table("probes")
    diameter = fields.numbers(pr, "diameter_mm", [5.5], problems, source)
    depth = fields.numbers(pr, "depth_mm", [3.5], problems, source)
    pr.check_unknown()
    if thickness is not None:
        for k, d in enumerate(depth):
            if d >= thickness:
                problems.append(
                    Problem(
                        f"press depth {d} mm is not inside the {thickness} mm skin",
                        source,
                        f"probes.depth_mm[{k}]",
                        "press less deep than the skin is thick",
                    )
                )

    ex = table("excitation")
    amplitude = ex.number("amplitude_a", 0.002, positive=True, unit="A")
    rails = ex.number("rails_v", 8.0, positive=True, unit="V")
    ex.check_unknown()

    acq = table("acquisition")
    rate = acq.number("rate_hz", 10_000.0, positive=True, unit="Hz")
    settle = acq.integer("settle_samples", 20, minimum=0)
    live = acq.integer("live_samples", 100, minimum=1)
    brk = acq.integer("break_samples", 2, minimum=2)
    acq.check_unknown()

    no = table("noise")
    noise_model = no.choice("model", NOISE_MODELS, "lockin")
    noise_std = no.number("std_ohm", 1.0, positive=True, unit="ohm")
    v_noise = no.number("voltage_noise_v", 2e-3, minimum=0.0, unit="V")
    i_noise = no.number("current_noise_a", 1e-7, minimum=0.0, unit="A")
    quantise = no.boolean("quantise", True)
    sweeps = no.integer("sweeps_per_press", 1, minimum=1)
    no.check_unknown()

    le = table("learned")
    learned = LearnedSpec(
        enabled=bool(le.boolean("enabled", False)),
        positions=le.integer("positions", 120, minimum=8) or 120,
        repeats=le.integer("repeats", 4, minimum=1) or 4,
        seeds=le.integer("seeds", 3, minimum=1) or 3,
        test_share=le.number("test_share", 0.25, minimum=0.05, maximum=0.8) or 0.25,
        model=le.choice("model", LEARNED_MODELS, "knn") or "knn",
    )
    le.check_unknown()

    inv = table("inversion")
    offsets = fields.as_list(inv, "depth_offsets_mm", [-0.5, 0.0, 0.5])
    if not offsets or not all(isinstance(o, (int, float)) and not isinstance(o, bool) for o in offsets):
        problems.append(
            Problem(
                f"depth_offsets_mm must list numbers (mm), got {offsets!r}",
                source,
                "inversion.depth_offsets_mm",
                "write depth_offsets_mm = [-0.5, 0.0, 0.5]",
            )
        )
        offsets = [0.0]
    inversion = InversionSpec(
        enabled=bool(inv.boolean("enabled", False)),
        draws=inv.integer("draws", 2, minimum=1) or 2,
        library=inv.integer("library", 40, minimum=4) or 40,
        depth_offsets_mm=tuple(float(o) for o in offsets),
        iterations=inv.integer("iterations", 6, minimum=0) or 0,
        starts=inv.integer("starts", 3, minimum=1) or 3,
    )
    inv.check_unknown()

    if problems:
        raise ConfigError(problems=problems)
    return Study(
        name=str(name),
        source=source,
        seed=int(seed or 0),
        description=str(description),
        scene=str(scene),
        fidelity=str(fidelity),
        criterion=str(crit),
        press_grid=int(press_grid or 25),
        sizes=tuple(sizes),
        pitch_mm=tuple(pitch),
        channel_width_mm=tuple(width),
        channel_height_mm=tuple(height),
        channel_depth_mm=float(channel_depth or 2.0),
        thickness_mm=float(thickness or 5.5),
        resistivity_ohm_m=float(resistivity or 0.5),
        counts=tuple(counts),
        strategies=tuple(strategies),
        every_k=int(every_k or 2),
        restarts=int(restarts if restarts is not None else 8),
        explicit=tuple(explicit),
        probe_diameter_mm=tuple(diameter),
        depth_mm=tuple(depth),
        amplitude_a=float(amplitude or 0.002),
        rails_v=float(rails or 8.0),
        rate_hz=float(rate or 10_000.0),
        settle_samples=int(settle if settle is not None else 20),
        live_samples=int(live or 100),
        break_samples=int(brk or 2),
        noise_model=str(noise_model),
        noise_std_ohm=float(noise_std or 1.0),
        voltage_noise_v=float(v_noise if v_noise is not None else 2e-3),
        current_noise_a=float(i_noise if i_noise is not None else 1e-7),
        quantise=bool(quantise),
        sweeps_per_press=int(sweeps or 1),
        learned=learned,
        inversion=inversion,
    )

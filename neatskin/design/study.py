"""The design study file: its validation (every problem at once, naming the file, the field and the fix) and the
Study value it becomes; its keys, units and ranges are declared in `neatskin.config.studyfile`, the checks across
keys (counts against the smallest grid, placements on junctions, depths inside the skin) are here. Expanding a study into candidates lives in `candidates.py`.

A study names a family of grid layouts (sizes N x M, pitch, channel cross-section), electrode counts and placement
strategies, probes (diameter, depth), the excitation and acquisition timing, the noise model, the scene and
optionally a learned-error estimate. protocols/studies/grid5.toml is the worked example; docs/design.md the guide.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neatskin.config import parse_tables
from neatskin.config.studyfile import (
    STUDY_NAME_PATTERN,
    ElectrodesTable,
    LayoutsTable,
    ProbesTable,
    StudyFile,
    StudyTable,
)
from neatskin.design import fields
from neatskin.design.fields import ExplicitPlacement
from neatskin.design.inversion import InversionSpec
from neatskin.errors import ConfigError, Problem
from neatskin.tomlfile import read_toml, resolve_path


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
    amplitude_a: float = 0.0002  # as protocols/paper.toml: 2 mA cannot pass the muxes' rails, 0.5 mA pressed pairs
    rails_v: float = 8.0
    r_on_ohm: float = 100.0
    r_on_mismatch_ohm: float = 10.0
    compliance_v: float = 50.0
    press_margin: float = 1.5
    adc_range_v: float = 10.0
    voltage_gain: float = 0.5
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


DEFAULT_OUT_ROOT = Path("out") / "design"


def load_study(path: str | Path) -> Study:
    """Read and validate a study TOML; one ConfigError listing every problem (file, field, fix)."""
    path = resolve_path(path)
    data = read_toml(path, "study file")
    if not data:
        # the docs promise no default study: an empty file is a mistake (a wrong path, an unsaved editor)
        raise ConfigError(
            "the study file is empty: it names no layouts, electrodes or probes to sweep",
            file=str(path),
            field="layouts",
            fix="start from a copy of protocols/studies/grid5.toml (every key commented) and edit it",
        )
    return study_from_dict(data, source=str(path))


FINGERPRINT = "study.json"  # a study folder's fingerprint of the study that wrote it (refuses a resume of another)
PARTS = "parts"  # a study folder's one-row parquet per candidate done (what resume skips, what validate reads)


def study_fingerprint(study: Study) -> dict[str, Any]:
    """Everything that changes a study's numbers (the source path and description do not)."""
    import json

    data = dataclasses.asdict(study)
    data.pop("source")
    data.pop("description")
    return json.loads(json.dumps(data))


def study_out_dir(study: Study, out: str | Path | None, root: Path = DEFAULT_OUT_ROOT) -> Path:
    """The folder a study writes into: `out` as given, else root/<name>, which must stay inside root.

    The name is validated as a name at load (no separator, no '..'); the resolved check also holds a name
    built in Python (study_from_dict with a hand-made Study) and a symlink planted at root/<name>."""
    if out is not None:
        return Path(out)
    folder = root / study.name
    inside = folder.resolve().parent == root.resolve()
    if not inside or Path(study.name).name != study.name or study.name in (".", ".."):
        raise ConfigError(
            f"the study's name {study.name!r} would write outside {root}/ (it resolves to {folder.resolve()})",
            file=study.source,
            field="study.name",
            fix="give a plain name (letters, digits, '.', '_', '-'), or choose the folder with --out",
        )
    return folder


def study_from_dict(data: dict[str, Any], source: str = "<memory>") -> Study:
    """The Study a TOML table describes (schema: neatskin.config.studyfile); one ConfigError listing every problem."""
    tables, problems = parse_tables(StudyFile, data, source)
    st: StudyTable | None = tables.get("study")
    lay: LayoutsTable | None = tables.get("layouts")
    el: ElectrodesTable | None = tables.get("electrodes")
    pr: ProbesTable | None = tables.get("probes")
    if st is not None and st.scene == "paper-like":
        problems.append(
            Problem(
                "scene 'paper-like' is not available yet (the variable paper-like skin is being added to skin/)",
                source,
                "study.scene",
                'use scene = "ideal" for now',
            )
        )
    if lay is not None:
        from neatskin.design.sensitivity import DENSE_MAX_JUNCTIONS

        for k, (nx, ny) in enumerate(lay.sizes):
            if nx * ny > DENSE_MAX_JUNCTIONS:
                problems.append(
                    Problem(
                        f"a {nx} x {ny} grid has {nx * ny} junctions; the study's dense network solve stops at "
                        f"{DENSE_MAX_JUNCTIONS}",
                        source,
                        f"layouts.sizes[{k}]",
                        f"use grids of at most {DENSE_MAX_JUNCTIONS} junctions (e.g. [50, 50])",
                    )
                )
    if lay is not None and lay.channel_depth_mm >= lay.thickness_mm:
        problems.append(
            Problem(
                f"channel_depth_mm = {lay.channel_depth_mm} is not inside the {lay.thickness_mm} mm skin",
                source,
                "layouts.channel_depth_mm",
                "set channel_depth_mm below thickness_mm",
            )
        )
    explicit: list[ExplicitPlacement] = []
    if el is not None:
        explicit = _explicit(el, problems, source)
        if "explicit" in el.strategies and not el.explicit:
            problems.append(
                Problem(
                    "strategy 'explicit' needs at least one [[electrodes.explicit]] placement",
                    source,
                    "electrodes.strategies",
                    "add [[electrodes.explicit]] with name and junctions_mm, or drop 'explicit'",
                )
            )
    if lay is not None and el is not None:
        smallest = min(lay.sizes, key=lambda s: s[0] * s[1])
        for k, count in enumerate(el.counts):
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
        fields.check_explicit_on_grid(explicit, list(lay.sizes), list(lay.pitch_mm), problems, source)
    if lay is not None and pr is not None:
        for k, d in enumerate(pr.depth_mm):
            if d >= lay.thickness_mm:
                problems.append(
                    Problem(
                        f"press depth {d} mm is not inside the {lay.thickness_mm} mm skin",
                        source,
                        f"probes.depth_mm[{k}]",
                        "press less deep than the skin is thick",
                    )
                )
    if problems:
        raise ConfigError(problems=problems)
    return _study(StudyFile(**tables), explicit, source)


def _explicit(el: ElectrodesTable, problems: list[Problem], source: str) -> list[ExplicitPlacement]:
    """The explicit placements, each named, with no junction listed twice."""
    out: list[ExplicitPlacement] = []
    for k, entry in enumerate(el.explicit):
        if len(set(entry.junctions_mm)) != len(entry.junctions_mm):
            where = f"electrodes.explicit[{k}].junctions_mm"
            problems.append(Problem("two electrodes on the same junction", source, where, "list each once"))
            continue
        out.append(ExplicitPlacement(entry.name or f"explicit{k + 1}", entry.junctions_mm))
    return out


def _name_from_stem(source: str) -> str:
    """The default name, the file's stem made a name (a stem may hold spaces or a leading dot)."""
    stem = Path(source).stem if source != "<memory>" else "study"
    name = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".")
    return name if re.fullmatch(STUDY_NAME_PATTERN, name) else "study"


def _study(f: StudyFile, explicit: list[ExplicitPlacement], source: str) -> Study:
    st, lay, el, no = f.study, f.layouts, f.electrodes, f.noise
    return Study(
        name=st.name or _name_from_stem(source),
        source=source,
        seed=st.seed,
        description=st.description,
        scene=st.scene,
        fidelity=st.fidelity,
        criterion=st.criterion,
        press_grid=st.press_grid,
        sizes=lay.sizes,
        pitch_mm=lay.pitch_mm,
        channel_width_mm=lay.channel_width_mm,
        channel_height_mm=lay.channel_height_mm,
        channel_depth_mm=lay.channel_depth_mm,
        thickness_mm=lay.thickness_mm,
        resistivity_ohm_m=lay.resistivity_ohm_m,
        counts=el.counts,
        strategies=el.strategies,
        every_k=el.every_k,
        restarts=el.restarts,
        explicit=tuple(explicit),
        probe_diameter_mm=f.probes.diameter_mm,
        depth_mm=f.probes.depth_mm,
        amplitude_a=f.excitation.amplitude_a,
        rails_v=f.excitation.rails_v,
        r_on_ohm=f.excitation.r_on_ohm,
        r_on_mismatch_ohm=f.excitation.r_on_mismatch_ohm,
        compliance_v=f.excitation.compliance_v,
        press_margin=f.excitation.press_margin,
        adc_range_v=f.acquisition.adc_range_v,
        voltage_gain=f.acquisition.voltage_gain,
        rate_hz=f.acquisition.rate_hz,
        settle_samples=f.acquisition.settle_samples,
        live_samples=f.acquisition.live_samples,
        break_samples=f.acquisition.break_samples,
        noise_model=no.model,
        noise_std_ohm=no.std_ohm,
        voltage_noise_v=no.voltage_noise_v,
        current_noise_a=no.current_noise_a,
        quantise=no.quantise,
        sweeps_per_press=no.sweeps_per_press,
        learned=LearnedSpec(**dataclasses.asdict(f.learned)),
        inversion=InversionSpec(**dataclasses.asdict(f.inversion)),
    )

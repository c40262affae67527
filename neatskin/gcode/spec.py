"""The G-code half of a campaign protocol: [campaign] name/seed, [files] layout/printer, [positions], [press].

`press_spec_from_dict(data, source)` reads exactly those sections of a parsed protocol TOML
(other sections are ignored, so the campaign's protocol loader can call it on the whole file) and
returns a frozen `GcodeSpec`; every problem in those sections is reported in one ConfigError.
`build_from_protocol(path)` loads the layout and printer profile it names and builds the program.
"""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neatskin.config import parse_collect, parse_partial
from neatskin.config.files import (
    MAX_PRESSES,
    CampaignTable,
    FilesTable,
    PositionSpec,
    PressSpec,
    ProtocolFile,
    campaign_name_problems,
)
from neatskin.config.kinds import wrong_kind_problem
from neatskin.errors import ConfigError, Problem, raise_problems
from neatskin.gcode.positions import generate_positions
from neatskin.gcode.profile import PrinterProfile, load_printer_profile
from neatskin.gcode.program import PressProgram, build_program
from neatskin.layout import Layout, load_layout
from neatskin.tomlfile import read_toml, resolve_path

GCODE_TABLES: tuple[tuple[str, type], ...] = (
    ("campaign", CampaignTable),
    ("files", FilesTable),
    ("positions", PositionSpec),
    ("press", PressSpec),
)


@dataclass(frozen=True)
class GcodeSpec:
    name: str
    seed: int
    layout_path: Path
    printer_path: Path
    positions: PositionSpec
    press: PressSpec
    source: str = "<memory>"


def _missing_table(data: dict, name: str, source: str) -> Problem:
    """Why a G-code section is not a table: an array of tables ([[press]]), a misspelt header, or absent."""
    value = data.get(name)
    if isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
        return Problem(
            f"[{name}] is written as an array of tables [[{name}]], but it is one table",
            source,
            name,
            f"write its header with single brackets: [{name}]",
        )
    if value is not None:
        return Problem(f"[{name}] must be a table, got {type(value).__name__}", source, name, f"write it as [{name}]")
    close = difflib.get_close_matches(name, [str(k) for k in data if k not in dict(GCODE_TABLES)], n=1, cutoff=0.6)
    if close:
        return Problem(f"unknown table [{close[0]}]", source, close[0], f"did you mean '{name}'?")
    return Problem(f"missing [{name}] table", source, name, f"add [{name}] (see protocols/paper.toml)")


def press_spec_from_dict(data: dict, source: str = "<memory>", base_dir: str | Path | None = None) -> GcodeSpec:
    """The G-code sections of a protocol; paths in [files] are resolved from `base_dir` (default: the source's folder).

    The sections are read with the protocol schema (`neatskin.config.files`); every problem in them is
    reported in one ConfigError. Other sections and [files].wiring are the campaign loader's."""
    problems: list[Problem] = []
    base = Path(base_dir) if base_dir is not None else Path(source).parent
    tables: dict[str, Any] = {}
    if not data:
        raise ConfigError("the file is empty", file=source, fix="write its tables (see protocols/paper.toml)")
    wrong = wrong_kind_problem(ProtocolFile, data, source)  # a layout or printer profile given as the protocol
    if wrong is not None:
        raise ConfigError(problems=[wrong])
    for name, schema in GCODE_TABLES:
        if not isinstance(data.get(name), dict):
            problems.append(_missing_table(data, name, source))
            continue
        if name == "files":  # the wiring is not the G-code's business
            partial, found = parse_partial(schema, data[name], source, name)
            for key in ("layout", "printer"):
                if key not in data[name]:
                    found.append(
                        Problem(
                            f"missing file path '{key}'",
                            source,
                            f"files.{key}",
                            f'set {key} = "{"skins" if key == "layout" else "printers"}/paper.toml" '
                            "(relative to the protocol file)",
                        )
                    )
            tables[name] = partial if not found else None
        else:
            tables[name], found = parse_collect(schema, data[name], source, name)
        problems += found
    campaign: CampaignTable | None = tables.get("campaign")
    files: dict[str, Any] | None = tables.get("files")
    positions: PositionSpec | None = tables.get("positions")
    press: PressSpec | None = tables.get("press")
    if positions is not None and campaign is not None and positions.seed is None:
        positions = dataclasses.replace(positions, seed=campaign.seed)
    if positions is not None and press is not None and positions.count * press.repeats > MAX_PRESSES:
        problems.append(
            Problem(
                f"{positions.count} positions x {press.repeats} repeats = {positions.count * press.repeats} presses, "
                f"more than {MAX_PRESSES} in one program",
                source,
                "press.repeats",
                "split the work into several campaigns",
            )
        )
    if problems or campaign is None or files is None or positions is None or press is None:
        raise ConfigError(problems=problems or [Problem("incomplete protocol", source, None, "see the errors above")])
    paths = {key: base / files[key] if not Path(files[key]).is_absolute() else Path(files[key]) for key in files}
    return GcodeSpec(campaign.name, campaign.seed, paths["layout"], paths["printer"], positions, press, source)


def load_gcode_spec(path: str | Path) -> GcodeSpec:
    """The G-code sections of a protocol file; its campaign name must also be a safe file name (G-code text)."""
    path = resolve_path(path)
    spec = press_spec_from_dict(read_toml(path, "protocol", fix="check the path"), str(path))
    raise_problems(campaign_name_problems(spec.name, str(path)))
    return spec


def build_from_spec(
    spec: GcodeSpec, *, hold_in_gcode: bool = False, layout: Layout | None = None, profile: PrinterProfile | None = None
) -> tuple[PressProgram, Layout, PrinterProfile]:
    """Load what the spec names (unless given) and build its press program."""
    layout = layout if layout is not None else _load_named(load_layout, spec, "layout", spec.layout_path)
    profile = profile if profile is not None else _load_named(load_printer_profile, spec, "printer", spec.printer_path)
    positions = generate_positions(layout, spec.positions)
    program = build_program(
        layout,
        positions,
        spec.press,
        profile,
        name=spec.name,
        seed=spec.seed,
        hold_in_gcode=hold_in_gcode,
        source=spec.source,
    )
    return program, layout, profile


def _load_named(load: Any, spec: GcodeSpec, key: str, path: Path) -> Any:
    """Load a file the protocol names; a file that cannot be read at all is named by the protocol's field."""
    try:
        return load(path)
    except ConfigError as exc:
        if all(p.field is not None for p in exc.problems):
            raise
        raise ConfigError(
            problems=[
                p if p.field is not None else Problem(f"{p.message}: {p.file}", spec.source, f"files.{key}", p.fix)
                for p in exc.problems
            ]
        ) from exc


def build_from_protocol(path: str | Path, *, hold_in_gcode: bool = True) -> tuple[PressProgram, Layout, PrinterProfile]:
    return build_from_spec(load_gcode_spec(path), hold_in_gcode=hold_in_gcode)

"""The G-code half of a campaign protocol: [campaign] name/seed, [files] layout/printer, [positions], [press].

`press_spec_from_dict(data, source)` reads exactly those sections of a parsed protocol TOML
(other sections are ignored, so the lead's protocol loader can call it on the whole file) and
returns a frozen `GcodeSpec`; every problem in those sections is reported in one ConfigError.
`build_from_protocol(path)` loads the layout and printer profile it names and builds the program.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path

from neatskin.errors import ConfigError, Problem
from neatskin.gcode.positions import PositionSpec, generate_positions
from neatskin.gcode.profile import PrinterProfile, load_printer_profile
from neatskin.gcode.program import PressProgram, PressSpec, build_program
from neatskin.layout import Layout, load_layout
from neatskin.tomlfile import read_toml, resolve_path

POSITION_KEYS = {
    "strategy",
    "count",
    "seed",
    "min_spacing_mm",
    "electrode_keep_out_mm",
    "keep_out",
    "channel_fraction",
    "grid_shape",
}
PRESS_KEYS = {"depth_mm", "repeats", "order", "hold_s", "probe_diameter_mm", "travel_ordering", "depth_margin_mm"}


@dataclass(frozen=True)
class GcodeSpec:
    name: str
    seed: int
    layout_path: Path
    printer_path: Path
    positions: PositionSpec
    press: PressSpec
    source: str = "<memory>"


def press_spec_from_dict(data: dict, source: str = "<memory>", base_dir: str | Path | None = None) -> GcodeSpec:
    """The G-code sections of a protocol; paths in [files] are resolved from `base_dir` (default: the source's folder)."""
    problems: list[Problem] = []
    base = Path(base_dir) if base_dir is not None else Path(source).parent

    def table(name: str) -> dict:
        value = data.get(name)
        if not isinstance(value, dict):
            problems.append(
                Problem(f"missing [{name}] table", source, name, f"add [{name}] (see protocols/paper.toml)")
            )
            return {}
        return value

    campaign, files, positions, press = table("campaign"), table("files"), table("positions"), table("press")
    name = campaign.get("name")
    if not isinstance(name, str) or not name:
        problems.append(
            Problem(
                f"campaign name must be non-empty text, got {name!r}",
                source,
                "campaign.name",
                'set name = "my-campaign"',
            )
        )
        name = "campaign"
    seed = campaign.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        problems.append(
            Problem(
                f"seed must be a whole number >= 0, got {seed!r}",
                source,
                "campaign.seed",
                "set seed = 2019 (any whole number; it fixes positions and order)",
            )
        )
        seed = 0
    paths = {}
    for key in ("layout", "printer"):
        value = files.get(key)
        if not isinstance(value, str) or not value:
            problems.append(
                Problem(
                    f"missing file path '{key}'",
                    source,
                    f"files.{key}",
                    f'set {key} = "{key}s/paper.toml" (relative to the protocol file)'
                    if key == "printer"
                    else 'set layout = "skins/paper.toml"',
                )
            )
            paths[key] = Path()
        else:
            paths[key] = (base / value) if not Path(value).is_absolute() else Path(value)
    for tname, tab, known in (("positions", positions, POSITION_KEYS), ("press", press, PRESS_KEYS)):
        for key in sorted(set(tab) - known):
            close = difflib.get_close_matches(key, sorted(known), n=1)
            problems.append(
                Problem(
                    f"unknown key '{key}'",
                    source,
                    f"{tname}.{key}",
                    f"did you mean '{close[0]}'?" if close else f"remove it or use one of: {', '.join(sorted(known))}",
                )
            )
    for tname, tab, key, fix in (
        ("positions", positions, "strategy", 'set strategy = "paper", "stratified" or "grid"'),
        ("positions", positions, "count", "set count to the number of distinct positions"),
        ("press", press, "depth_mm", "set depth_mm (below the skin's top surface; 3.5 in the paper)"),
        ("press", press, "repeats", "set repeats (presses per position; 28 in the paper)"),
    ):
        if tab and key not in tab:
            problems.append(Problem(f"missing '{key}'", source, f"{tname}.{key}", fix))
    pos_spec = press_spec = None
    try:
        kwargs = {k: v for k, v in positions.items() if k in POSITION_KEYS}
        kwargs.setdefault("seed", seed)
        if "keep_out" in kwargs:
            kwargs["keep_out"] = tuple(tuple(float(v) for v in z) for z in kwargs["keep_out"])
        if "grid_shape" in kwargs:
            kwargs["grid_shape"] = tuple(kwargs["grid_shape"])
        pos_spec = PositionSpec(**kwargs, source=source)
    except ConfigError as exc:
        problems.extend(exc.problems)
    except (TypeError, ValueError) as exc:
        problems.append(
            Problem(
                f"malformed value: {exc}",
                source,
                "positions",
                "keep_out is a list of [x_mm, y_mm, radius_mm]; grid_shape is [rows, cols]",
            )
        )
    try:
        press_spec = PressSpec(**{k: v for k, v in press.items() if k in PRESS_KEYS}, source=source)
    except ConfigError as exc:
        problems.extend(exc.problems)
    if problems:
        raise ConfigError(problems=problems)
    return GcodeSpec(name, seed, paths["layout"], paths["printer"], pos_spec, press_spec, source)


def load_gcode_spec(path: str | Path) -> GcodeSpec:
    path = resolve_path(path)
    return press_spec_from_dict(read_toml(path, "protocol", fix="check the path"), str(path))


def build_from_spec(
    spec: GcodeSpec, *, hold_in_gcode: bool = False, layout: Layout | None = None, profile: PrinterProfile | None = None
) -> tuple[PressProgram, Layout, PrinterProfile]:
    """Load what the spec names (unless given) and build its press program."""
    layout = layout if layout is not None else load_layout(spec.layout_path)
    profile = profile if profile is not None else load_printer_profile(spec.printer_path)
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


def build_from_protocol(path: str | Path, *, hold_in_gcode: bool = True) -> tuple[PressProgram, Layout, PrinterProfile]:
    return build_from_spec(load_gcode_spec(path), hold_in_gcode=hold_in_gcode)

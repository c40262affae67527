"""docs/config.md, generated from the schemas: one table per file kind with every key, unit, default and constraint.

    python -m neatskin.config.docs > docs/config.md

A test compares the committed file with this output, so the reference cannot drift from the code.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from typing import Any

from neatskin.config import files
from neatskin.config.declare import (
    constraint_of,
    describe_range,
    hints,
    is_required,
    is_schema,
    key_fields,
    toml_key,
)
from neatskin.config.kinds import FILE_KINDS

INTRO = """# Configuration files

Every TOML file the toolkit reads has a schema in `neatskin/config/` (`files.py`: the protocol,
layout and wiring; `scene.py`: the protocol's `[scene]`; `printerfile.py`; `studyfile.py`): frozen
dataclasses whose fields carry their unit, default, range and a line of documentation (the spirit of
scikit-learn's `_parameter_constraints`). One engine (`neatskin/config/schema.py`) reads a file
against its schema and reports **every** problem at once, each as `file: [field]: what (fix: how)`:
a wrong type, a value out of range (NaN and infinities are never numbers here), a missing key,
and any unknown key or table at any level, with the closest known name ("did you mean 'park'?").
A loader then checks what spans several keys or files (soft limits inside the bed, a wiring
against its layout, a press inside the skin, the excitation against the electrical limits) and
returns a fully typed value.

Files are read by `neatskin.tomlfile.read_toml`: only regular files of at most 4 MiB of UTF-8
text; a device (`/dev/zero`), a folder, a binary file or an over-long path is one error naming
the file. A `[files]` entry that is a loop of links (`ln -s loop.toml loop.toml`) is a ConfigError naming
the protocol and the field (`files.layout`: "a loop of symbolic links"), before any folder is made.
A path starting with `protocols/` that does not exist where you are falls back to the
packaged copy (`neatskin/protocols/`), so the defaults work from any folder and from a wheel.

The tables are the values the code uses: `PressSpec` (`[press]`), `PositionSpec` (`[positions]`),
`Scene` (`[scene]`), `Excitation`, `AcquisitionSettings` and `PrinterTable` (which `PrinterProfile`
extends) are declared once and check every value at construction (`neatskin.config.settings`), with
the file's own text: `PressSpec(depth_mm=5000, repeats=1)` in Python raises the ConfigError a protocol
with `depth_mm = 5000` gets, so a value the file refuses cannot exist in memory, and the defaults are
the same in both.

Choice: frozen dataclasses with constraint metadata rather than pydantic or msgspec: no new
dependency, frozen dataclasses are already the toolkit's value types, the engine collects every
problem of a file with a "did you mean" for a misspelt key (pydantic's errors would have to be
translated back into the file, field and fix text), and the problem text stays the toolkit's own.

`campaign check` also refuses what the run cannot execute: beyond each key's range below, one
press may record at most {max_samples:,} samples, a campaign at most {max_gib} GiB of waveforms
and {max_days} days of rig time, a program at most {max_presses:,} presses; the campaign name must be
a safe ASCII file name; and the peak excitation voltage must stay within the electrical limits
(docs/acquisition.md, "Electrical limits").

This file is generated: `python -m neatskin.config.docs > docs/config.md`.
"""


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if origin in (typing.Union, __import__("types").UnionType):
        return _type_name(args[0])
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is dict:
        return "table"
    return {float: "number", int: "integer", bool: "boolean", str: "text"}.get(tp, getattr(tp, "__name__", str(tp)))


def _default(f: dataclasses.Field) -> str:
    c = constraint_of(f)
    if is_required(f):
        return "**required**"
    if c.default_doc:
        return c.default_doc
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return "empty"
    value = f.default
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if value == ():
        return "none"
    if isinstance(value, tuple):
        return _toml(value)
    return f"{value!r}"


def _toml(value: Any) -> str:
    """A default as it is written in the file: [[3, 3]], ["boundary"]."""
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return f'"{value}"' if isinstance(value, str) else repr(value)


def _rows(schema: type, prefix: str, out: list[str], nested: list[tuple[str, type, bool]]) -> None:
    types_ = hints(schema)
    for f in key_fields(schema):
        tp = types_[f.name]
        key = f"{prefix}{toml_key(f)}"
        inner = typing.get_args(tp)
        if is_schema(tp):
            nested.append((key, tp, False))
            continue
        if typing.get_origin(tp) is tuple and inner and is_schema(inner[0]):
            nested.append((key, inner[0], True))
            continue
        c = constraint_of(f)
        doc = c.doc or f.metadata.get("neatskin.table_doc", "")
        out.append(f"| `{key}` | {_type_name(tp)} | {c.unit or ''} | {_default(f)} | {describe_range(c)} | {doc} |")


def render_schema(title: str, schema: type) -> str:
    lines = [f"## {title}", "", inspect.cleandoc(schema.__doc__ or ""), ""]
    top: list[str] = []
    nested: list[tuple[str, type, bool]] = []
    _rows(schema, "", top, nested)
    header = ["| key | type | unit | default | constraint | meaning |", "|---|---|---|---|---|---|"]
    if top:
        lines += ["Top-level keys:", "", *header, *top, ""]
    while nested:  # tables in order, a table's own sub-tables ([[electrodes.explicit]]) right after it
        key, table, is_array = nested.pop(0)
        owner = schema if "." not in key else None
        required = [f for f in key_fields(owner) if toml_key(f) == key and is_required(f)] if owner else []
        kind = f"[[{key}]]" if is_array else f"[{key}]"
        lines.append(f"### `{kind}`" + (" (required)" if required else " (optional)"))
        lines.append("")
        if table.__doc__ and not table.__doc__.startswith(table.__name__ + "("):
            lines += [inspect.cleandoc(table.__doc__), ""]
        rows: list[str] = []
        inner: list[tuple[str, type, bool]] = []
        _rows(table, "", rows, inner)
        lines += [*header, *rows, ""]
        nested[:0] = [(f"{key}.{sub}", tp, array) for sub, tp, array in inner]
    return "\n".join(lines)


MISTAKES = """## Mistakes and what they print

One mistake is one line, `file: [field]: what (fix: how)`, nothing written (`campaign check`
exits 1, a failed check; `campaign run` and `gcode generate` exit 3, a configuration error: docs/cli.md): a
misspelt key or table is reported as unknown with its close name, and not once more as missing;
an empty file is "the file is empty"; what follows from a problem already reported (the channels
naming a junction whose entry is bad, the pair left unrouted by a pin wired twice, each press of
a campaign a wrong offset puts off the bed) is not reported again. Files with a byte-order mark
or CRLF line ends read as the same file. Beyond each key's range, the loaders check across keys
and files: the excitation below Nyquist and at least one whole period in the live window (and in
the RMS window), so a Hz/kHz slip fails; a probe narrower than the skin; a wiring whose own
`layout` key names a file that exists and the protocol's skin; a `rotation_deg` that is not a
radian value (within 5e-5 of a multiple of pi/4).

| mistake | what `neatskin campaign check protocols/paper.toml` prints |
|---|---|
| `[campain]` | `paper.toml: [campain]: unknown table [campain] (fix: did you mean 'campaign'?)` |
| `[[press]]` | `paper.toml: [press]: [press] is written as an array of tables [[press]], but it is one table (fix: write its header with single brackets: [press])` |
| `depth_mm = 35` | `paper.toml: [press.depth_mm]: press depth 35.0 mm is beyond the skin thickness 5.5 mm minus the 0.5 mm margin (limit 5 mm) (fix: set depth_mm <= 5)` |
| `enabled = "true"` | `paper.toml: [fsr.enabled]: 'enabled' must be true or false, got 'true' (fix: set enabled = true or false)` |
| `frequency_hz = 1.0` | `paper.toml: [excitation.frequency_hz]: the live_samples of 100 samples (10 ms at 10000 Hz) holds 0.01 periods of the 1 Hz excitation; ...` |
| `amplitude_a = 0.002` | `paper.toml: [excitation.amplitude_a]: the excitation would clip: 2 mA x (...) = 17.3 V peak, beyond the mux supply rails ...` |
| `probe_diameter_mm = 55` | `paper.toml: [press.probe_diameter_mm]: a 55 mm probe is wider than the skin (30 x 30 mm between its outer junctions) ...` |
| a channel `to = "J23"` | `skins/paper.toml: [channels[11].to]: unknown junction 'J23' (fix: use one of the junction names: J00, ...)` |
| `x_mm = "15.0"` | `skins/paper.toml: [junctions[1].x_mm]: 'x_mm' must be a finite number, got '15.0' (...)` |
| a pair wired twice | `wiring/paper.toml: [chips[6].pins.X3/Y3]: pair 1-2 is routed twice: ... (fix: ...; pairs not routed by any chip: 7-8)` |
| pin `YO` | `wiring/paper.toml: [chips[0].pins.YO]: chip 'U1' has no pin 'YO' (fix: did you mean 'Y0'? ...)` |
| `[parking]` | `printers/paper.toml: [parking]: unknown table [parking] (fix: did you mean 'park'?)` |
| `rotation_deg = 1.5708` | `printers/paper.toml: [calibration.rotation_deg]: rotation_deg = 1.5708 looks like 90 degrees written in radians ...` |
| `offset_x_mm = 250` | `paper.toml: [press 0]: press 0 (position 0) goes to printer x = 279.153 mm, outside the bed and soft limits [0, 220] mm; so do 2799 more presses ...` |

`gcode generate` reads only what the program needs (`[campaign]`, `[files]` layout and printer,
`[positions]`, `[press]`); a mistake elsewhere (`[fsr]`, `[scene]`, the wiring, the excitation)
is `campaign check`'s, and `campaign run` refuses it before anything moves.
"""


def render_markdown() -> str:
    intro = INTRO.format(
        max_samples=files.MAX_SAMPLES_PER_PRESS,
        max_gib=files.MAX_WAVEFORM_BYTES // 2**30,
        max_days=int(files.MAX_RIG_TIME_S // 86400),
        max_presses=files.MAX_PRESSES,
    )
    parts = [intro]
    for title, schema in FILE_KINDS.items():
        parts.append(render_schema(title.capitalize(), schema))
    parts.append(MISTAKES)
    parts.append(
        "## Scene presets\n\nThe protocol's `[scene]` keys are listed above; the values each preset gives the knobs "
        "left out of the table live in `neatskin/sim/scene.py` (`PRESETS`; what is fitted and what is assumed: "
        "docs/skin.md). `campaign check` also refuses a `surface_error_mm` beyond the skin's thickness, a "
        '`placement_error_mm` beyond 100 mm, `scene.signal = "features"` with `record.waveforms = true`, and '
        "`hysteresis_fraction > 0` with `relaxation_time_s = 0`.\n"
    )
    return "\n".join(parts)


if __name__ == "__main__":
    print(render_markdown(), end="")

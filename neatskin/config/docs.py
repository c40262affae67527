"""docs/config.md, generated from the schemas: one table per file kind with every key, unit, default and constraint.

    python -m neatskin.config.docs > docs/config.md

A test compares the committed file with this output, so the reference cannot drift from the code.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from neatskin.config import files
from neatskin.config.schema import constraint_of, describe_range, hints, is_required, is_schema, toml_key

INTRO = """# Configuration files

Every TOML file the toolkit reads has a schema in `neatskin/config/files.py`: frozen dataclasses
whose fields carry their unit, default, range and a line of documentation (the spirit of
scikit-learn's `_parameter_constraints`). One engine (`neatskin/config/schema.py`) reads a file
against its schema and reports **every** problem at once, each as `file: [field]: what (fix: how)`:
a wrong type, a value out of range (NaN and infinities are never numbers here), a missing key,
and any unknown key or table at any level, with the closest known name ("did you mean 'park'?").
A loader then checks what spans several keys or files (soft limits inside the bed, a wiring
against its layout, a press inside the skin, the excitation against the electrical limits) and
returns a fully typed value.

Files are read by `neatskin.tomlfile.read_toml`: only regular files of at most 4 MiB of UTF-8
text; a device (`/dev/zero`), a folder, a binary file or an over-long path is one error naming
the file. A path starting with `protocols/` that does not exist where you are falls back to the
packaged copy (`neatskin/protocols/`), so the defaults work from any folder and from a wheel.

Choice: frozen dataclasses with constraint metadata rather than pydantic or msgspec: no new
dependency, frozen dataclasses are already the toolkit's value types, and the problem text
(file, field, fix) stays the toolkit's own.

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
    return f"{value!r}"


def _rows(schema: type, prefix: str, out: list[str], nested: list[tuple[str, type, bool]]) -> None:
    types_ = hints(schema)
    for f in dataclasses.fields(schema):
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
    lines = [f"## {title}", "", (schema.__doc__ or "").strip(), ""]
    top: list[str] = []
    nested: list[tuple[str, type, bool]] = []
    _rows(schema, "", top, nested)
    header = ["| key | type | unit | default | constraint | meaning |", "|---|---|---|---|---|---|"]
    if top:
        lines += ["Top-level keys:", "", *header, *top, ""]
    for key, table, is_array in nested:
        required = [f for f in dataclasses.fields(schema) if toml_key(f) == key and is_required(f)]
        kind = f"[[{key}]]" if is_array else f"[{key}]"
        lines.append(f"### `{kind}`" + (" (required)" if required else " (optional)"))
        lines.append("")
        if table.__doc__ and not table.__doc__.startswith(table.__name__ + "("):
            lines += [table.__doc__.strip(), ""]
        rows: list[str] = []
        _rows(table, "", rows, [])
        lines += [*header, *rows, ""]
    return "\n".join(lines)


def render_markdown() -> str:
    intro = INTRO.format(
        max_samples=files.MAX_SAMPLES_PER_PRESS,
        max_gib=files.MAX_WAVEFORM_BYTES // 2**30,
        max_days=int(files.MAX_RIG_TIME_S // 86400),
        max_presses=files.MAX_PRESSES,
    )
    parts = [intro]
    for title, schema in files.FILE_KINDS.items():
        parts.append(render_schema(title.capitalize(), schema))
    parts.append(
        "## Scene\n\nThe protocol's `[scene]` (what a dry run simulates) is declared and read by "
        "`neatskin/sim/scene.py`; see docs/campaigns.md. `campaign check` also refuses a "
        "`surface_error_mm` beyond the skin's thickness and a `placement_error_mm` beyond 100 mm.\n"
    )
    return "\n".join(parts)


if __name__ == "__main__":
    print(render_markdown(), end="")

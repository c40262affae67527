"""The file kinds (protocol, layout, wiring, printer profile, design study) and reading a whole file of one kind.

Above the schemas (`files`, `printerfile`, `studyfile`) and the engine (`schema`): knowing every kind lets a loader
say "this is a layout file, not a wiring" instead of listing every table as unknown.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from neatskin.config.declare import is_required, key_fields, toml_key
from neatskin.config.files import LayoutFile, ProtocolFile, WiringFile
from neatskin.config.printerfile import PrinterFile
from neatskin.config.schema import parse_valid
from neatskin.config.studyfile import StudyFile
from neatskin.errors import Problem

FILE_KINDS: dict[str, type] = {
    "protocol": ProtocolFile,
    "layout": LayoutFile,
    "wiring": WiringFile,
    "printer profile": PrinterFile,
    "design study": StudyFile,
}


def parse_tables(schema: type, data: Any, source: str) -> tuple[dict[str, Any], list[Problem]]:
    """Every top-level field of `schema` that reads cleanly (defaults included), and every problem.

    For loaders whose cross-field checks should still run on the good tables of a file with bad ones."""
    if not isinstance(data, Mapping):
        return {}, [
            Problem(f"the file must hold TOML tables, got {type(data).__name__}", source, None, "check the file")
        ]
    wrong = wrong_kind_problem(schema, data, source)
    if wrong is not None:
        return {}, [wrong]
    return parse_valid(schema, data, source)


def wrong_kind_problem(schema: type, data: Mapping, source: str) -> Problem | None:
    """A file of another kind (a layout named where a wiring belongs): one problem, not one per table."""
    own_keys = {toml_key(f) for f in key_fields(schema)}
    if not data or own_keys & set(data):
        return None
    own = next((title for title, kind in FILE_KINDS.items() if kind is schema), "")
    for title, kind in FILE_KINDS.items():
        required = [toml_key(f) for f in key_fields(kind) if is_required(f)]
        if kind is not schema and required and all(key in data for key in required):
            shown = ", ".join(f"[{key}]" for key in required)
            return Problem(
                f"this is a {title} file (it has {shown}), not a {own or 'file of this kind'}",
                source,
                None,
                f"name a {own} file here: check the protocol's [files] entry or the path given",
            )
    return None

"""The one config layer: declarative schemas of every TOML file kind (`files`), the engine that reads them
(`schema`), the generated reference (`docs`), and `TableReader` (key-by-key reading, kept for sim/scene.py)."""

from neatskin.config.schema import (
    Constraint,
    parse,
    parse_collect,
    parse_partial,
    parse_tables,
    setting,
    unknown_key_problems,
)
from neatskin.config.tables import TableReader

__all__ = [
    "Constraint",
    "TableReader",
    "parse",
    "parse_collect",
    "parse_partial",
    "parse_tables",
    "setting",
    "unknown_key_problems",
]

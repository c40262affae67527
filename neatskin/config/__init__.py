"""The one config layer: declarative schemas of every TOML file kind (`files`), the engine that reads them
(`schema`) and the generated reference (`docs`)."""

from neatskin.config.schema import (
    Constraint,
    parse,
    parse_collect,
    parse_partial,
    parse_tables,
    setting,
    unknown_key_problems,
)

__all__ = [
    "Constraint",
    "parse",
    "parse_collect",
    "parse_partial",
    "parse_tables",
    "setting",
    "unknown_key_problems",
]

"""The one config layer: declarative schemas of every TOML file kind (`files`, `scene`, `printerfile`, `studyfile`),
how a setting is declared (`declare`), the engine that reads them (`schema`), validation at construction
(`settings`), the file kinds (`kinds`) and the generated reference (`docs`)."""

from neatskin.config.declare import Constraint, setting
from neatskin.config.kinds import parse_tables
from neatskin.config.schema import parse, parse_collect, parse_partial, unknown_key_problems

__all__ = [
    "Constraint",
    "parse",
    "parse_collect",
    "parse_partial",
    "parse_tables",
    "setting",
    "unknown_key_problems",
]

"""Reading the toolkit's TOML files (protocols, layouts, wirings, printer profiles) with errors that name the file."""

from __future__ import annotations

import tomllib
from pathlib import Path

from neatskin.errors import ConfigError


def read_toml(path: str | Path, what: str, fix: str = "check the path (the paths in a protocol's [files] are "
              "relative to the protocol file's folder; on the command line, to the current folder)") -> dict:
    """Parse a TOML file; a missing file or a syntax error is one ConfigError naming the file (and the line)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read {what}: {exc.strerror}", file=str(path), fix=fix) from exc
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", file=str(path), field="<syntax>",
                          fix="correct the TOML syntax at that line") from exc

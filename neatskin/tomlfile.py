"""Reading the toolkit's TOML files (protocols, layouts, wirings, printer profiles) with errors that name the file,
and the one resolver of the packaged defaults (`protocols/`, shipped as package data in `neatskin/protocols/`)."""

from __future__ import annotations

import importlib.resources
import tomllib
from pathlib import Path

from neatskin.errors import ConfigError

PACKAGED_FOLDER = "protocols"


def packaged_protocols() -> Path:
    """The folder of the packaged protocols, skins, wirings, printers and studies (works from a wheel)."""
    return Path(str(importlib.resources.files("neatskin").joinpath(PACKAGED_FOLDER)))


def resolve_path(path: str | Path) -> Path:
    """A path as given if it exists; else, if it starts with `protocols/`, the packaged copy of that file.

    So `neatskin campaign run protocols/paper.toml` works from any folder and from an installed
    wheel, while a user's own `protocols/` folder (or any existing file) always wins."""
    given = Path(path)
    if given.exists() or given.is_absolute() or not given.parts or given.parts[0] != PACKAGED_FOLDER:
        return given
    packaged = packaged_protocols().joinpath(*given.parts[1:])
    return packaged if packaged.exists() else given


def read_toml(
    path: str | Path,
    what: str,
    fix: str = "check the path (the paths in a protocol's [files] are "
    "relative to the protocol file's folder; on the command line, to the current folder)",
) -> dict:
    """Parse a TOML file; a missing file or a syntax error is one ConfigError naming the file (and the line)."""
    path = resolve_path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read {what}: {exc.strerror}", file=str(path), fix=fix) from exc
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(
            f"not valid TOML: {exc}", file=str(path), field="<syntax>", fix="correct the TOML syntax at that line"
        ) from exc

"""Reading the toolkit's TOML files (protocols, layouts, wirings, printer profiles) with errors that name the file,
and the one resolver of the packaged defaults (`protocols/`, shipped as package data in `neatskin/protocols/`)."""

from __future__ import annotations

import importlib.resources
import os
import stat
import tomllib
from pathlib import Path

from neatskin.errors import ConfigError

PACKAGED_FOLDER = "protocols"


def packaged_protocols() -> Path:
    """The folder of the packaged protocols, skins, wirings, printers and studies (works from a wheel)."""
    return Path(str(importlib.resources.files("neatskin").joinpath(PACKAGED_FOLDER)))


MAX_TOML_BYTES = 4 * 2**20  # no protocol, layout, wiring or profile comes near this; /dev/zero would


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:  # a name too long, say: not a file we could read, so not "existing" either
        return False


def resolve_path(path: str | Path) -> Path:
    """A path as given if it exists; else, if it starts with `protocols/`, the packaged copy of that file.

    So `neatskin campaign run protocols/paper.toml` works from any folder and from an installed
    wheel, while a user's own `protocols/` folder (or any existing file) always wins."""
    given = Path(path)
    if _exists(given) or given.is_absolute() or not given.parts or given.parts[0] != PACKAGED_FOLDER:
        return given
    packaged = packaged_protocols().joinpath(*given.parts[1:])
    return packaged if _exists(packaged) else given


def read_text_capped(path: Path, what: str, fix: str, max_bytes: int = MAX_TOML_BYTES) -> str:
    """The UTF-8 text of a regular file of at most max_bytes; anything else is one ConfigError naming the file."""
    try:
        with open(path, "rb") as handle:
            mode = os.fstat(handle.fileno()).st_mode
            if not stat.S_ISREG(mode):
                raise ConfigError(
                    f"{what} is not a regular file (a device, folder or pipe)",
                    file=str(path),
                    fix=f"name a TOML file; {fix}",
                )
            data = handle.read(max_bytes + 1)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise ConfigError(f"cannot read {what}: {reason}", file=_short(path), fix=fix) from exc
    if len(data) > max_bytes:
        raise ConfigError(
            f"{what} is larger than {max_bytes // 2**20} MiB: not a TOML file of this toolkit",
            file=str(path),
            fix=f"name the right file; {fix}",
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{what} is not UTF-8 text (byte {exc.start}: {data[exc.start : exc.start + 1]!r})",
            file=str(path),
            field="<encoding>",
            fix="save the file as UTF-8 (TOML files are UTF-8), or name the right file",
        ) from exc


def _short(path: Path) -> str:
    text = str(path)
    return text if len(text) <= 300 else f"{text[:150]}...{text[-100:]} ({len(text)} characters)"


def read_toml(
    path: str | Path,
    what: str,
    fix: str = "check the path (the paths in a protocol's [files] are "
    "relative to the protocol file's folder; on the command line, to the current folder)",
) -> dict:
    """Parse a TOML file; a missing, unreadable, non-regular, oversized or non-UTF-8 file, or a syntax error,
    is one ConfigError naming the file (and the line)."""
    path = resolve_path(path)
    # a byte-order mark (Windows Notepad writes one) is not TOML, but it hides nothing: read past it
    text = read_text_capped(path, what, fix).removeprefix("\ufeff")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(
            f"not valid TOML: {exc}", file=str(path), field="<syntax>", fix="correct the TOML syntax at that line"
        ) from exc

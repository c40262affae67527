"""Reading the toolkit's TOML files (protocols, layouts, wirings, printer profiles) with errors that name the file,
the one capped text reader (TOML files and G-code programs alike), and the one resolver of the packaged defaults
(`protocols/`, shipped as package data in `neatskin/protocols/`)."""

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


def read_text_capped(
    path: str | os.PathLike[str],
    what: str,
    fix: str,
    max_bytes: int = MAX_TOML_BYTES,
    *,
    kind: str = "TOML file",
    refuse_nul: bool = False,
) -> str:
    """The UTF-8 text of a regular file of at most max_bytes, past a byte-order mark; anything else is one
    ConfigError naming the file, what was read (`what`, e.g. "protocol file", "G-code file") and the fix.

    `kind` names what such a file is ("TOML file", "G-code file"), for the messages; `refuse_nul` refuses a file
    with a NUL byte (a parquet or an image decodes as UTF-8 up to its first non-ASCII byte; a text file has none).
    A device or a pipe is refused before anything is read: a serial port named by mistake would block the read."""
    name = os.fspath(path)
    wrong_file = f"name the right file; {fix}"
    try:
        with open(name, "rb") as handle:
            mode = os.fstat(handle.fileno()).st_mode
            if not stat.S_ISREG(mode):
                raise ConfigError(
                    f"{what} is not a regular file (a device, folder or pipe)",
                    file=_short(name),
                    fix=f"name a {kind}; {fix}",
                )
            data = handle.read(max_bytes + 1)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise ConfigError(f"cannot read {what}: {reason}", file=_short(name), fix=fix) from exc
    if len(data) > max_bytes:
        raise ConfigError(
            f"{what} is larger than {max_bytes // 2**20} MiB: not a {kind} of this toolkit",
            file=_short(name),
            fix=wrong_file,
        )
    nul = data.find(b"\0") if refuse_nul else -1
    if nul >= 0:
        raise ConfigError(
            f"{what} holds NUL bytes (the first at byte {nul}): a binary file (parquet, image, ...), not a {kind}",
            file=_short(name),
            field="<encoding>",
            fix=wrong_file,
        )
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{what} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})",
            file=_short(name),
            field="<encoding>",
            fix=f"save the file as UTF-8 ({kind}s are UTF-8 text), or {wrong_file}",
        ) from None
    # a byte-order mark (Windows Notepad writes one) is neither TOML nor G-code, but it hides nothing: read past it
    return text.removeprefix("\ufeff")


def _short(path: str | os.PathLike[str]) -> str:
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
    text = read_text_capped(path, what, fix)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(
            f"not valid TOML: {exc}", file=str(path), field="<syntax>", fix="correct the TOML syntax at that line"
        ) from exc

"""`neatskin protocol init DIR`: a protocol and every hardware file it names, copied as a template to edit.

`cp -r protocols mine` copies the repository's `protocols` link, which dangles in `mine`; this copies regular
files only, following each reference (the protocol's `[files]`, a wiring's `layout`, ...) so the copy is whole:
`neatskin campaign check DIR/paper.toml` reads nothing outside DIR.
"""

from __future__ import annotations

import os
import re
import shutil
import tomllib
from pathlib import Path
from typing import Any

from neatskin.errors import ConfigError
from neatskin.tomlfile import packaged_protocols, resolve_path

MAX_FILES = 64  # a protocol names four files; a reference loop or a runaway tree stops here


def _toml_references(data: Any) -> list[str]:
    """Every string value ending in .toml, at any depth: the files a TOML file names."""
    if isinstance(data, dict):
        return [ref for value in data.values() for ref in _toml_references(value)]
    if isinstance(data, list):
        return [ref for value in data for ref in _toml_references(value)]
    return [data] if isinstance(data, str) and data.lower().endswith(".toml") else []


def source_protocol(name: str) -> Path:
    """The protocol to copy: a file path, or the name of a packaged one (`paper`, `smoke`)."""
    given = resolve_path(name)
    if given.is_file():
        return given
    packaged = packaged_protocols() / f"{name}.toml"
    if packaged.is_file():
        return packaged
    names = sorted(p.stem for p in packaged_protocols().glob("*.toml"))
    raise ConfigError(
        f"no protocol {name!r}",
        field="--from",
        fix=f"name a protocol file, or one of the packaged protocols: {', '.join(names)}",
    )


def _read(path: Path) -> tuple[str, dict[str, Any]]:
    try:
        text = path.read_text(encoding="utf-8")
        return text, tomllib.loads(text)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read it as TOML: {exc}", file=str(path), fix="copy from a valid protocol") from exc


def init_protocol(out: str | os.PathLike, source: str = "paper") -> list[Path]:
    """Copy the protocol `source` and the files it names (transitively) into the new folder `out`, keeping
    their paths relative to the protocol; a file outside the protocol's folder is copied beside the others
    and the reference to it rewritten. Returns the files written, the protocol first."""
    protocol = source_protocol(source)
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError("the folder exists and is not empty", file=str(out), fix="name a new folder")
    root = protocol.resolve().parent
    targets: dict[Path, Path] = {protocol.resolve(): out / protocol.name}
    queue = [protocol.resolve()]
    texts: dict[Path, str] = {}
    while queue:
        current = queue.pop(0)
        text, data = _read(current)
        for ref in _toml_references(data):
            found = (current.parent / ref).resolve()
            if not found.is_file():
                raise ConfigError(
                    f"it names {ref!r}, which does not exist (looked for {found})",
                    file=str(current),
                    fix="copy from a protocol whose files exist (neatskin campaign check shows which)",
                )
            if found not in targets:
                if len(targets) >= MAX_FILES:
                    raise ConfigError(f"it names more than {MAX_FILES} files", file=str(current), fix="trim it")
                inside = found.is_relative_to(root)
                targets[found] = out / (found.relative_to(root) if inside else Path("external") / found.name)
                queue.append(found)
            target_ref = os.path.relpath(targets[found], targets[current].parent).replace(os.sep, "/")
            if target_ref != ref:  # only a file from outside the protocol's folder moves
                quoted = re.compile(rf"([\"']){re.escape(ref)}\1")
                text = quoted.sub(lambda m: m.group(1) + target_ref + m.group(1), text)  # noqa: B023 (used at once)
        texts[current] = text
    written = []
    for source_path, target in targets.items():
        target.parent.mkdir(parents=True, exist_ok=True)
        if texts[source_path] == source_path.read_text(encoding="utf-8"):
            shutil.copyfile(source_path, target)  # a regular file, never a link, whatever the source is
        else:
            target.write_text(texts[source_path], encoding="utf-8")
        written.append(target)
    return written

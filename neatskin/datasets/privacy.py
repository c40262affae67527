"""What an export may say about the recording machine: nothing. Host names and absolute local paths are
removed from manifests and parquet metadata before they leave the lab (pure functions over JSON values).

A campaign folder keeps its host (the folder lock names the machine that holds it) and the absolute paths of
its input files (`source`: where the protocol was read from); an export is read elsewhere, where neither means
anything and both say who recorded where. Relative paths inside the dataset (`inputs/layout.toml`) stay.
"""

from __future__ import annotations

import re
import socket
from collections.abc import Iterable
from typing import Any

DROPPED_KEYS = frozenset({"host", "hostname", "source", "folder", "cwd", "user"})  # local by nature
LOCAL_PATH = "<local path>"
LOCAL_HOST = "<host>"
# an absolute path: POSIX (/x/y, ~/x) or Windows (C:\x, \\server\share); not a ratio like 3/98 or a URL's path
_ABSOLUTE = re.compile(r"(?<![\w.:/~])(?:~?/(?:[\w.@+-]+/?)+|[A-Za-z]:\\[^\s\"']*|\\\\[^\s\"']+)")


def host_names() -> set[str]:
    """This machine's names (short and fully qualified): what must not appear in an export."""
    names = {socket.gethostname()}
    try:
        names.add(socket.getfqdn())
    except OSError:  # a resolver that fails leaves the short name
        pass
    names |= {n.split(".")[0] for n in names}
    return {n for n in names if n and n not in ("localhost", "localhost.localdomain")}


def scrub_text(text: str, hosts: Iterable[str] = ()) -> str:
    """A string with every absolute path replaced by <local path> and every host name by <host>."""
    text = _ABSOLUTE.sub(LOCAL_PATH, text)
    for host in sorted(set(hosts), key=len, reverse=True):  # the longest first: a fqdn before its short name
        if len(host) >= 2:
            text = re.sub(rf"(?<![\w-]){re.escape(host)}(?![\w-])", LOCAL_HOST, text)
    return text


def scrub(value: Any, hosts: Iterable[str] | None = None) -> Any:
    """A JSON value without local facts: the keys of DROPPED_KEYS removed at every depth, absolute paths and
    host names replaced in every string. `hosts` defaults to this machine's names; callers add the manifest's
    recorded host (the recording machine may not be this one)."""
    names = set(host_names() if hosts is None else hosts)
    return _scrub(value, names)


def _scrub(value: Any, hosts: set[str]) -> Any:
    if isinstance(value, dict):
        return {k: _scrub(v, hosts) for k, v in value.items() if str(k) not in DROPPED_KEYS}
    if isinstance(value, (list, tuple)):
        return [_scrub(v, hosts) for v in value]
    if isinstance(value, str):
        return scrub_text(value, hosts)
    return value


def recorded_hosts(*manifests: dict[str, Any]) -> set[str]:
    """The host names the manifests recorded (the machines that ran the campaigns), with this machine's."""
    hosts = host_names()
    for manifest in manifests:
        for key in ("host", "hostname"):
            if isinstance(manifest.get(key), str):
                hosts.add(manifest[key])
        for source in manifest.get("merged_from", []) or []:
            if isinstance(source, dict) and isinstance(source.get("manifest"), dict):
                hosts |= recorded_hosts(source["manifest"])
    return hosts

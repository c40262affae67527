"""Linux /proc helpers for the tests that kill a run outright: its child processes, and whether one still runs."""

from __future__ import annotations

from pathlib import Path


def children(pid: int, command_part: bytes = b"") -> list[int]:
    """The running (not zombie) processes whose parent is pid and whose command line holds command_part."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z" and command_part in cmdline:
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """pid exists and is not a zombie waiting for its reaper."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False

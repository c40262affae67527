"""The campaign folder's layout: file names and how to list the durable parts in it.

CAMPAIGN/
  manifest.json                      protocol as run, provenance, status, counts
  campaign.lock                      who runs the campaign (PID, host, start); flock'ed while it runs
  presses.parquet                    all presses, one row each (after finalize)
  presses.copy.parquet               a byte copy of presses.parquet kept by finalize, to restore a damaged one
  physical_limit.parquet             a dry run's bound on the position error per position
  presses/part-000042.parquet        durable presses while the campaign runs: press 42 and, in a dry run's
                                     batched part, the presses after it (ids strictly increasing)
  waveforms/position_id=7/part-000042.parquet   raw samples of press 42 (hive-partitioned)
"""

from __future__ import annotations

import re
from pathlib import Path

from neatskin.campaignread import MANIFEST_NAME as MANIFEST_NAME  # re-exported: the one name, read on the ground floor

CONSOLIDATED_NAME = "presses.parquet"
COPY_NAME = "presses.copy.parquet"
PHYSICAL_LIMIT = "physical_limit.parquet"  # a dry run's Cramér-Rao bounds per position (neatskin.rig.physlimit)
PRESSES_DIR = "presses"
WAVEFORMS_DIR = "waveforms"
_PART = re.compile(r"^part-(\d+)\.parquet$")


def part_name(press_id: int) -> str:
    return f"part-{press_id:06d}.parquet"


def part_press_id(path: Path) -> int | None:
    """The press id of a durable part file (of its first row), or None for anything else (temp files
    included)."""
    match = _PART.match(path.name)
    return int(match.group(1)) if match else None


def press_parts(folder: Path) -> dict[int, Path]:
    """{first press id: part path} of the durable press parts in CAMPAIGN/presses/."""
    parts_dir = Path(folder) / PRESSES_DIR
    if not parts_dir.is_dir():
        return {}
    out = {}
    for entry in parts_dir.iterdir():
        press_id = part_press_id(entry)
        if press_id is not None:
            out[press_id] = entry
    return dict(sorted(out.items()))


def waveform_parts(folder: Path) -> dict[int, Path]:
    """{press_id: waveform part path} under CAMPAIGN/waveforms/position_id=K/."""
    root = Path(folder) / WAVEFORMS_DIR
    if not root.is_dir():
        return {}
    out = {}
    for sub in root.iterdir():
        if sub.is_dir() and sub.name.startswith("position_id="):
            for entry in sub.iterdir():
                press_id = part_press_id(entry)
                if press_id is not None:
                    out[press_id] = entry
    return dict(sorted(out.items()))

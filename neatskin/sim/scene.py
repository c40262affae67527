"""The `[scene]` of a protocol read for a dry run: the table's value and what it must agree with elsewhere.

`Scene` (the keys, units, ranges, presets and the checks within the table) is declared once in
`neatskin.config.scene` and listed in docs/config.md; this module re-exports it for the simulation
and reads a `[scene]` table with `parse_scene`, which reports every problem at once (the protocol
loader collects them with the rest of the file's) and checks the scene against the `[record]` table.
The physical basis of each knob and where its preset value comes from: docs/skin.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from neatskin.config.scene import PAPER_LIKE, PRESETS, SCENE_KNOBS, Scene
from neatskin.config.schema import build, parse_valid
from neatskin.errors import Problem

__all__ = ["PAPER_LIKE", "PRESETS", "PRESET_KNOBS", "Scene", "parse_scene"]

PRESET_KNOBS = SCENE_KNOBS


def parse_scene(raw: Mapping[str, Any] | Scene, source: str, *, record_waveforms: bool) -> tuple[Scene, list[Problem]]:
    """The scene a `[scene]` table (raw, or already read by the protocol's schema) describes, and every problem.

    A bad value is in the problems; the scene then holds the default in its place."""
    problems: list[Problem] = []
    if isinstance(raw, Scene):
        scene = raw
        signal: str | None = raw.signal
    else:
        good, problems = parse_valid(Scene, raw, source, "scene")  # a bad value left out: the default stands in
        built, cross = build(Scene, good, source, "scene")
        problems += cross
        scene = built if built is not None else Scene()
        # the signal the table gives, not the default that stands in for a table with another bad value (an
        # invalid preset, a NaN placement error); a bad signal is its own problem already
        signal = None if any(p.field == "scene.signal" for p in problems) else good.get("signal", Scene().signal)
    if signal == "features" and record_waveforms:
        problems.append(
            Problem(
                "record.waveforms = true needs the waveforms to be simulated",
                source,
                "scene.signal",
                'set scene.signal = "waveforms" or record.waveforms = false',
            )
        )
    return scene, problems

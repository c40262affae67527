"""The `[scene]` of a protocol: what a dry run simulates (the skin model's fidelity, the signal level, the rig effects).

Each knob is one field of `Scene` with its unit in the name; `parse_scene` reads the protocol's
`[scene]` table and reports every problem at once (the protocol loader collects them with the
rest of the file's).
"""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.config import TableReader
from neatskin.errors import Problem


@dataclass(frozen=True)
class Scene:
    """What a dry run simulates: the skin model's fidelity, the signal level, the rig effects."""

    fidelity: str  # "deformation" | "network"
    signal: str  # "features" | "waveforms"
    noise: bool
    placement_error_mm: float
    surface_error_mm: float = 0.0  # the real skin surface lies this far below the calibrated one


def parse_scene(raw: dict, source: str, *, record_waveforms: bool) -> tuple[Scene, list[Problem]]:
    """The scene a `[scene]` table describes, and every problem found in it."""
    scene_t = TableReader(raw, "scene", source)
    fidelity = scene_t.choice("fidelity", ("deformation", "network"), "deformation")
    signal = scene_t.choice("signal", ("features", "waveforms"), "features")
    noise = scene_t.boolean("noise", True)
    placement = scene_t.number("placement_error_mm", 0.0, minimum=0.0, unit="mm")
    surface_error = scene_t.number("surface_error_mm", 0.0, unit="mm")
    if signal == "features" and record_waveforms:
        scene_t.problems.append(
            Problem(
                "record.waveforms = true needs the waveforms to be simulated",
                source,
                "scene.signal",
                'set scene.signal = "waveforms" or record.waveforms = false',
            )
        )
    scene_t.check_unknown()
    return Scene(fidelity, signal, noise, placement, surface_error), scene_t.problems

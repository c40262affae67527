"""Campaign protocol files: load a protocol TOML and the layout, wiring and printer profile it names.

Validation reports every error in the protocol (and in the files it references) at once,
each with its file, field and fix, before anything moves.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from neatskin.config import TableReader
from neatskin.errors import ConfigError, Problem
from neatskin.sim.scene import Scene, parse_scene
from neatskin.tomlfile import read_toml, resolve_path

KNOWN_SECTIONS = ("campaign", "files", "positions", "press", "excitation", "acquisition", "fsr", "record", "scene")


@dataclass(frozen=True)
class Excitation:
    amplitude_a: float
    frequency_hz: float


@dataclass(frozen=True)
class AcquisitionSettings:
    rate_hz: float
    settle_samples: int
    live_samples: int
    demodulation: str
    window: int


@dataclass(frozen=True)
class Protocol:
    path: Path
    name: str
    seed: int
    description: str
    layout_path: Path
    wiring_path: Path
    printer_path: Path
    layout: object  # neatskin.layout.Layout
    wiring: object  # neatskin.acquisition.wiring.Wiring
    printer: object  # neatskin.gcode.profile.PrinterProfile
    press: object  # the G-code side of the protocol: positions and press program parameters
    excitation: Excitation
    acquisition: AcquisitionSettings
    fsr_enabled: bool
    record_waveforms: bool
    scene: Scene
    raw: dict

    @property
    def referenced_files(self) -> dict[str, Path]:
        return {
            "protocol": self.path,
            "layout": self.layout_path,
            "wiring": self.wiring_path,
            "printer": self.printer_path,
        }


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_protocol(path: str | Path, file_overrides: dict[str, Path] | None = None) -> Protocol:
    """Load and validate a protocol and everything it references; raise one ConfigError listing every problem.

    file_overrides replaces the layout, wiring or printer file the protocol names (resume uses the
    copies kept in the campaign folder)."""
    path = resolve_path(path)
    source = str(path)
    data = read_toml(path, "protocol file", fix="check the path, e.g. protocols/paper.toml")

    problems: list[Problem] = []
    for section in data:
        if section not in KNOWN_SECTIONS:
            problems.append(
                Problem(
                    f"unknown section [{section}]",
                    source,
                    section,
                    f"remove it; known sections: {', '.join(KNOWN_SECTIONS)}",
                )
            )

    def table(name: str) -> TableReader:
        raw = data.get(name, {})
        reader = TableReader(raw if isinstance(raw, dict) else {}, name, source)
        if not isinstance(raw, dict):
            reader.problems.append(Problem(f"[{name}] must be a table", source, name, f"write it as [{name}]"))
        return reader

    campaign = table("campaign")
    name = campaign.text("name")
    seed = campaign.integer("seed", minimum=0)
    description = campaign._get("description", "") or ""
    campaign.check_unknown()

    files = table("files")
    file_paths: dict[str, Path | None] = {}
    for key in ("layout", "wiring", "printer"):
        rel = files.text(key)
        file_paths[key] = None
        if rel is None:
            continue
        resolved = Path((file_overrides or {}).get(key) or (path.parent / rel)).resolve()
        if not resolved.is_file():
            files.problems.append(
                Problem(
                    f"{key} file {rel!r} does not exist (looked for {resolved})",
                    source,
                    f"files.{key}",
                    f"give a path relative to {path.parent}",
                )
            )
        else:
            file_paths[key] = resolved
    files.check_unknown()

    excitation_t = table("excitation")
    amplitude = excitation_t.number("amplitude_a", positive=True, maximum=0.1, unit="A")
    frequency = excitation_t.number("frequency_hz", positive=True, unit="Hz")
    excitation_t.check_unknown()

    acq = table("acquisition")
    rate = acq.number("rate_hz", positive=True, unit="Hz")
    settle = acq.integer("settle_samples", minimum=0)
    live = acq.integer("live_samples", minimum=2)
    demod = acq.choice("demodulation", ("rms", "lockin"))
    window = acq.integer("window", minimum=2)
    if None not in (live, window) and window > live:
        acq.problems.append(
            Problem(
                f"window {window} is longer than the live window {live}",
                source,
                "acquisition.window",
                "set window <= live_samples",
            )
        )
    if None not in (rate, frequency) and frequency >= rate / 2:
        acq.problems.append(
            Problem(
                f"excitation {frequency} Hz is at or above Nyquist for {rate} Hz sampling",
                source,
                "excitation.frequency_hz",
                "sample at least 2x faster than the excitation",
            )
        )
    acq.check_unknown()

    fsr = table("fsr")
    fsr_enabled = fsr.boolean("enabled", True)
    fsr.check_unknown()

    record = table("record")
    waveforms = record.boolean("waveforms", False)
    record.check_unknown()

    raw_scene = data.get("scene", {})
    scene, scene_problems = parse_scene(
        raw_scene if isinstance(raw_scene, dict) else {}, source, record_waveforms=bool(waveforms)
    )
    if not isinstance(raw_scene, dict):
        scene_problems.append(Problem("[scene] must be a table", source, "scene", "write it as [scene]"))
    problems.extend(scene_problems)

    for reader in (campaign, files, excitation_t, acq, fsr, record):
        problems.extend(reader.problems)

    layout, wiring, printer, press = _load_components(data, source, file_paths, problems)
    if None not in (layout, printer, press):  # the press program's checks: bounds after calibration, depth, feeds
        from neatskin.gcode.spec import build_from_spec

        _collect(problems, lambda: build_from_spec(press, layout=layout, profile=printer))

    if problems:
        raise ConfigError(problems=problems)
    return Protocol(
        path=path.resolve(),
        name=name,
        seed=seed,
        description=str(description),
        layout_path=file_paths["layout"],
        wiring_path=file_paths["wiring"],
        printer_path=file_paths["printer"],
        layout=layout,
        wiring=wiring,
        printer=printer,
        press=press,
        excitation=Excitation(amplitude, frequency),
        acquisition=AcquisitionSettings(rate, settle, live, demod, window),
        fsr_enabled=fsr_enabled,
        record_waveforms=waveforms,
        scene=scene,
        raw=data,
    )


def _collect(problems: list[Problem], load, *args):
    try:
        return load(*args)
    except ConfigError as exc:
        problems.extend(exc.problems)
        return None


def _load_components(data: dict, source: str, paths: dict, problems: list[Problem]):
    from neatskin.acquisition.wiring import load_wiring
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.gcode.spec import press_spec_from_dict
    from neatskin.layout import load_layout

    layout = _collect(problems, load_layout, paths["layout"]) if paths["layout"] else None
    printer = _collect(problems, load_printer_profile, paths["printer"]) if paths["printer"] else None
    wiring = _collect(problems, load_wiring, paths["wiring"], layout) if paths["wiring"] and layout else None
    own_fields = {p.field for p in problems}
    spec_problems: list[Problem] = []
    press = _collect(spec_problems, press_spec_from_dict, data, source)
    # [campaign] and [files] are checked here too: report each of their fields once
    problems.extend(
        p for p in spec_problems if not (p.field in own_fields and p.field.split(".")[0] in ("campaign", "files"))
    )
    return layout, wiring, printer, press

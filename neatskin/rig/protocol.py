"""Campaign protocol files: load a protocol TOML and the layout, wiring and printer profile it names.

The protocol is read through its schema (`neatskin.config.files.ProtocolFile`); then what spans
several keys or files is checked: the referenced files, the press program's bounds, the resources
the run would take (samples per press, bytes, rig time, each against a stated cap), the scene's
ranges, and the electrical limits (peak excitation voltage against the mux rails, the
galvanostat's compliance and the ADC range); those two figures and their limits are
`rig.protocollimits`'. Every problem in the protocol and the files it references is reported at
once, each with its file, field and fix, before anything moves.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neatskin.acquisition.wiring import load_wiring
from neatskin.config import files as schema
from neatskin.config import parse_tables
from neatskin.config.files import AcquisitionSettings, Excitation
from neatskin.errors import ConfigError, Problem
from neatskin.gcode.profile import load_printer_profile
from neatskin.gcode.spec import build_from_spec, press_spec_from_dict
from neatskin.layout import load_layout
from neatskin.oserrors import errno_of, fix_for
from neatskin.rig.protocollimits import (  # re-exported: railcheck and the design study import them from here
    CLIP_MESSAGE,
    ElectricalCheck,
    ResourceEstimate,
    check_electrical,
    electrical_check,
    electrical_problems,
    estimate_resources,
    resource_cap_problems,
)
from neatskin.sim.scene import Scene, parse_scene
from neatskin.tomlfile import read_toml, resolve_path

KNOWN_SECTIONS = ("campaign", "files", "positions", "press", "excitation", "acquisition", "fsr", "record", "scene")
MAX_PLACEMENT_ERROR_MM = 100.0

__all__ = [
    "CLIP_MESSAGE",
    "CampaignProtocol",
    "ElectricalCheck",
    "ResourceEstimate",
    "check_electrical",
    "electrical_check",
    "estimate_resources",
    "file_sha256",
    "load_protocol",
]


@dataclass(frozen=True)
class CampaignProtocol:
    path: Path
    name: str
    seed: int
    description: str
    layout_path: Path
    wiring_path: Path
    printer_path: Path
    layout: Any  # neatskin.layout.Layout
    wiring: Any  # neatskin.acquisition.wiring.Wiring
    printer: Any  # neatskin.gcode.profile.PrinterProfile
    press: Any  # neatskin.gcode.spec.GcodeSpec: positions and press program parameters
    excitation: Excitation
    acquisition: AcquisitionSettings
    fsr_enabled: bool
    fsr_pause_after_misses: int
    record_waveforms: bool
    scene: Scene
    raw: dict
    resources: ResourceEstimate
    electrical: ElectricalCheck
    skin_profile_path: Path | None = None  # [files] skin_profile, resolved
    skin_profile: Any = None  # the SkinModel it describes (neatskin.skin.fit.load_skin_profile), or None

    @property
    def referenced_files(self) -> dict[str, Path]:
        files = {
            "protocol": self.path,
            "layout": self.layout_path,
            "wiring": self.wiring_path,
            "printer": self.printer_path,
        }
        if self.skin_profile_path is not None:
            files["skin_profile"] = self.skin_profile_path
        return files


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_protocol(
    path: str | Path, file_overrides: dict[str, Path] | None = None, amplitude_a: float | None = None
) -> CampaignProtocol:
    """Load and validate a protocol and everything it references; raise one ConfigError listing every problem.

    file_overrides replaces the layout, wiring or printer file the protocol names (resume uses the
    copies kept in the campaign folder); amplitude_a replaces the excitation's current (`campaign check`'s
    figures for its suggested current when the file's is refused)."""
    path = resolve_path(path)
    source = str(path)
    data = read_toml(path, "protocol file", fix="check the path, e.g. protocols/paper.toml")
    tables, problems = parse_tables(schema.ProtocolFile, data, source)
    campaign: schema.CampaignTable | None = tables.get("campaign")
    if campaign is not None:
        problems += schema.campaign_name_problems(campaign.name, source)
    file_paths = _referenced_files(tables.get("files"), path, file_overrides or {}, problems)
    excitation_t: Excitation | None = tables.get("excitation")
    if excitation_t is not None and amplitude_a is not None:
        excitation_t = dataclasses.replace(excitation_t, amplitude_a=float(amplitude_a))
    acq: AcquisitionSettings | None = tables.get("acquisition")
    if acq is not None and excitation_t is not None:
        problems += _timing_problems(excitation_t, acq, source)
    record: schema.RecordTable = tables.get("record") or schema.RecordTable()
    fsr: schema.FsrTable = tables.get("fsr") or schema.FsrTable()
    # a [scene] that failed its schema (an invalid preset, a NaN) is not read: its signal is not known, so the
    # cross-check with [record] waits for the fix instead of blaming the default's signal
    scene_failed = "scene" not in tables and isinstance(data.get("scene"), dict)
    scene, scene_problems = parse_scene(
        tables.get("scene", {}), source, record_waveforms=record.waveforms and not scene_failed
    )
    problems.extend(scene_problems)

    layout, wiring, printer, press = _load_components(data, source, file_paths, problems)
    if layout is not None and not scene_problems:
        problems += _scene_problems(scene, layout, source)
    skin_profile = None
    if layout is not None and press is not None and file_paths.get("skin_profile") is not None:
        skin_profile = _load_skin_profile(file_paths["skin_profile"], layout, press, source, problems)
    resources = electrical = None
    resource_problems: list[Problem] = []  # a program too large to run is too large to build: check first
    if press is not None and printer is not None and acq is not None:
        resources = estimate_resources(press, printer, acq, record.waveforms)
        resource_problems = resource_cap_problems(resources, press, acq, source)
        problems += resource_problems
    if layout is not None and printer is not None and press is not None and not resource_problems:
        # the press program's checks: bounds after calibration, depth, feeds
        built: list[Problem] = []
        _collect(built, lambda: build_from_spec(press, layout=layout, profile=printer))
        reported = {p.field for p in problems}  # a field the schema refused (a non-ASCII name) is reported once
        problems += [p for p in built if p.field not in reported]
    if layout is not None and wiring is not None and excitation_t is not None and acq is not None:
        electrical = check_electrical(layout, wiring, excitation_t, acq)
        problems += electrical_problems(electrical, layout, wiring, excitation_t, source)

    if problems or campaign is None or excitation_t is None or acq is None or resources is None or electrical is None:
        raise ConfigError(
            problems=problems or [Problem("incomplete protocol", source, None, "see protocols/paper.toml")]
        )
    return CampaignProtocol(
        path=path.resolve(),
        name=campaign.name,
        seed=campaign.seed,
        description=campaign.description,
        layout_path=file_paths["layout"],
        wiring_path=file_paths["wiring"],
        printer_path=file_paths["printer"],
        layout=layout,
        wiring=wiring,
        printer=printer,
        press=press,
        excitation=excitation_t,
        acquisition=acq,
        fsr_enabled=fsr.enabled,
        fsr_pause_after_misses=fsr.pause_after_misses,
        record_waveforms=record.waveforms,
        scene=scene,
        raw=data,
        resources=resources,
        electrical=electrical,
        skin_profile_path=file_paths.get("skin_profile"),
        skin_profile=skin_profile,
    )


def _load_skin_profile(profile_path: Path, layout: Any, press: Any, source: str, problems: list[Problem]) -> Any:
    """The SkinModel of `[files] skin_profile` on the protocol's layout, or None with its problems added."""
    from neatskin.skin.fit import load_skin_profile  # the skin model: a protocol without a profile never loads it

    try:
        return load_skin_profile(profile_path, layout, probe_radius_mm=press.press.probe_diameter_mm / 2)
    except ConfigError as exc:
        problems += [
            Problem(p.message, p.file, p.field, f"{p.fix or 'fix the profile'} (it is files.skin_profile of {source})")
            for p in exc.problems
        ]
        return None


def _timing_problems(excitation: Excitation, acq: AcquisitionSettings, source: str) -> list[Problem]:
    """The excitation against the sampling: below Nyquist, and at least one whole period in the live window
    (and in the RMS window): a kHz/Hz slip (rate_hz = 10, frequency_hz = 1) fails here, with the units said."""
    f_hz, rate_hz = excitation.frequency_hz, acq.rate_hz
    if f_hz >= rate_hz / 2:
        return [
            Problem(
                f"excitation {f_hz:g} Hz is at or above Nyquist for {rate_hz:g} Hz sampling",
                source,
                "excitation.frequency_hz",
                f"sample at least 2x faster than the excitation: acquisition.rate_hz > {2 * f_hz:g} "
                "(both are in Hz: 10 kHz is rate_hz = 10000.0), or lower frequency_hz",
            )
        ]
    samples_per_period = rate_hz / f_hz
    for key, samples in (("live_samples", acq.live_samples), ("window", acq.window)):
        if key == "window" and acq.demodulation != "rms":
            continue
        if samples < samples_per_period:
            return [
                Problem(
                    f"the {key} of {samples} samples ({1000 * samples / rate_hz:g} ms at {rate_hz:g} Hz) holds "
                    f"{samples / samples_per_period:.3g} periods of the {f_hz:g} Hz excitation; a resistance "
                    "needs at least one whole period",
                    source,
                    "excitation.frequency_hz",
                    f"frequency_hz is in Hz (1 kHz is 1000.0): set it >= {rate_hz / samples:g}, "
                    f"or acquisition.{key} >= {math.ceil(samples_per_period)}",
                )
            ]
    return []


def _wiring_layout_problems(wiring: Any, layout: Any, wiring_path: Path) -> list[Problem]:
    """A wiring's own `layout` reference must exist and name the protocol's skin (else it was drawn for another)."""
    ref = getattr(wiring, "layout_path", None)
    if not ref:
        return []
    target = (wiring_path.parent / ref).resolve()
    if not target.is_file():
        return [
            Problem(
                f"the wiring names layout {ref!r}, which does not exist (looked for {target})",
                str(wiring_path),
                "layout",
                f"point layout at the protocol's skin file ({layout.source}), relative to the wiring file, "
                "or remove the key",
            )
        ]
    if target == Path(layout.source).resolve():
        return []
    try:
        named = load_layout(target)
    except ConfigError:
        return []  # the protocol's layout is the one used; a broken other file is `mux table`'s to report
    if named.name != layout.name:
        return [
            Problem(
                f"the wiring was drawn for layout '{named.name}' ({ref}), the protocol uses '{layout.name}'",
                str(wiring_path),
                "layout",
                f"use a wiring for '{layout.name}', or point its layout key at {layout.source}",
            )
        ]
    return []


def _path_fix(exc: BaseException) -> str:
    """The fix for a [files] path the OS refused, by its reason (`neatskin.oserrors`' table)."""
    code = errno.ELOOP if isinstance(exc, RuntimeError) else errno_of(exc)  # 3.11 says a loop as a RuntimeError
    return fix_for(code, "find", what="TOML file")


def _referenced_files(
    files: schema.FilesTable | None, path: Path, overrides: dict[str, Path], problems: list[Problem]
) -> dict[str, Any]:
    """Each [files] entry as an existing regular file (or the override resume gives), else a problem."""
    out: dict[str, Any] = {"layout": None, "wiring": None, "printer": None}
    if files is None:
        return out
    keys = [*out, "skin_profile"] if files.skin_profile is not None else list(out)
    for key in keys:
        rel = getattr(files, key)
        try:
            resolved = Path(overrides.get(key) or (path.parent / rel)).resolve()
            is_file = resolved.is_file()
        except (OSError, RuntimeError) as exc:  # a name too long, no permission, a loop of links (3.11: RuntimeError)
            loop = isinstance(exc, RuntimeError) or getattr(exc, "errno", None) == errno.ELOOP
            problems.append(
                Problem(
                    f"{key} file path cannot be used: "
                    + ("it is a loop of symbolic links" if loop else str(getattr(exc, "strerror", None) or exc)),
                    str(path),
                    f"files.{key}",
                    f"{_path_fix(exc)} (remove or repair the link {rel!r})" if loop else _path_fix(exc),
                )
            )
            continue
        if not is_file:
            what = "is not a regular file" if resolved.exists() else "does not exist"
            problems.append(
                Problem(
                    f"{key} file {rel!r} {what} (looked for {resolved})",
                    str(path),
                    f"files.{key}",
                    f"give a path to a TOML file, relative to the protocol's folder {path.parent.resolve()}",
                )
            )
        else:
            out[key] = resolved
    out["wiring_overridden"] = "wiring" in overrides  # resume's copy: its own layout key points nowhere useful
    return out


def _scene_problems(scene: Scene, layout: Any, source: str) -> list[Problem]:
    """Ranges of the finished Scene that depend on the layout (sim/scene.py checks each knob's type)."""
    problems = []
    if not abs(scene.surface_error_mm) <= layout.thickness_mm:
        problems.append(
            Problem(
                f"surface_error_mm = {scene.surface_error_mm!r} is not within the {layout.thickness_mm} mm skin",
                source,
                "scene.surface_error_mm",
                f"set surface_error_mm between -{layout.thickness_mm} and {layout.thickness_mm}",
            )
        )
    if not scene.placement_error_mm <= MAX_PLACEMENT_ERROR_MM:
        problems.append(
            Problem(
                f"placement_error_mm = {scene.placement_error_mm!r} is beyond {MAX_PLACEMENT_ERROR_MM:g} mm",
                source,
                "scene.placement_error_mm",
                "set a placement error std of a few mm at most (0 turns it off)",
            )
        )
    return problems


def _collect(problems: list[Problem], load: Any, *args: Any) -> Any:
    try:
        return load(*args)
    except ConfigError as exc:
        problems.extend(exc.problems)
        return None


def _load_components(data: dict, source: str, paths: dict, problems: list[Problem]) -> tuple[Any, Any, Any, Any]:
    layout = _collect(problems, load_layout, paths["layout"]) if paths["layout"] else None
    printer = _collect(problems, load_printer_profile, paths["printer"]) if paths["printer"] else None
    wiring = _collect(problems, load_wiring, paths["wiring"], layout) if paths["wiring"] and layout else None
    if wiring is not None and not paths.get("wiring_overridden"):
        problems.extend(_wiring_layout_problems(wiring, layout, paths["wiring"]))
    own_fields = {p.field for p in problems if p.file == source}
    spec_problems: list[Problem] = []
    press = _collect(spec_problems, press_spec_from_dict, data, source)
    # the protocol schema has read the G-code's sections too: report each field once
    problems.extend(p for p in spec_problems if p.field not in own_fields)
    return layout, wiring, printer, press

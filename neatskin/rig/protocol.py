"""Campaign protocol files: load a protocol TOML and the layout, wiring and printer profile it names.

The protocol is read through its schema (`neatskin.config.files.ProtocolFile`); then what spans
several keys or files is checked: the referenced files, the press program's bounds, the resources
the run would take (samples per press, bytes, rig time, each against a stated cap), the scene's
ranges, and the electrical limits (peak excitation voltage against the mux rails, the
galvanostat's compliance and the ADC range). Every problem in the protocol and the files it
references is reported at once, each with its file, field and fix, before anything moves.
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
from neatskin.sim.scene import Scene, parse_scene
from neatskin.skin.network import equivalent_resistance
from neatskin.tomlfile import read_toml, resolve_path

KNOWN_SECTIONS = ("campaign", "files", "positions", "press", "excitation", "acquisition", "fsr", "record", "scene")
WAVEFORM_BYTES_PER_SAMPLE = 3 * 8  # V, I, FSR as float64
MAX_PLACEMENT_ERROR_MM = 100.0


@dataclass(frozen=True)
class ResourceEstimate:
    """What the run would take, estimated from the protocol alone (upper bounds, before the plan is built)."""

    presses: int
    samples_per_press: int
    bytes_per_press: int  # one press's raw samples in memory
    waveform_bytes: int  # stored raw samples of the whole campaign (0 unless record.waveforms)
    rig_time_s: float

    def summary(self) -> str:
        return (
            f"{self.presses} presses, <= {self.samples_per_press} samples ({self.bytes_per_press / 2**20:.1f} MiB) "
            f"per press, {self.waveform_bytes / 2**30:.2f} GiB of waveforms, rig time <= {self.rig_time_s / 3600:.2f} h "
            "(a bound from the protocol alone: slowest feed, a bed-diagonal travel and 0.5 s of recording per "
            "press, homing; the campaign cap checks it)"
        )


@dataclass(frozen=True)
class ElectricalCheck:
    """The excitation's worst-case peak voltage on the undeformed skin times the press margin, and its limit."""

    largest_pair: str
    largest_r_eq_ohm: float
    peak_v: float
    limit_v: float
    limit_name: str

    @property
    def headroom(self) -> float:
        return self.limit_v / self.peak_v

    @property
    def within_limit(self) -> bool:
        """The verdict: the protocol is refused (and a design candidate marked not compliant) when False."""
        return self.peak_v <= self.limit_v

    def summary(self) -> str:
        return (
            f"peak {self.peak_v:.2f} V (pair {self.largest_pair}, {self.largest_r_eq_ohm:.0f} ohm undeformed, "
            f"with the press margin and R_on), limit {self.limit_v:.2f} V ({self.limit_name}), "
            f"{self.headroom:.2f}x headroom"
        )


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
        resource_problems = _resource_problems(resources, press, acq, source)
        problems += resource_problems
    if layout is not None and printer is not None and press is not None and not resource_problems:
        # the press program's checks: bounds after calibration, depth, feeds
        built: list[Problem] = []
        _collect(built, lambda: build_from_spec(press, layout=layout, profile=printer))
        reported = {p.field for p in problems}  # a field the schema refused (a non-ASCII name) is reported once
        problems += [p for p in built if p.field not in reported]
    if layout is not None and wiring is not None and excitation_t is not None and acq is not None:
        electrical = check_electrical(layout, wiring, excitation_t, acq)
        problems += _electrical_problems(electrical, layout, wiring, excitation_t, source)

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


def estimate_resources(press: Any, printer: Any, acq: AcquisitionSettings, waveforms: bool) -> ResourceEstimate:
    """Upper bounds of one press's samples and the campaign's bytes and rig time, from the protocol alone."""
    spec = press.press
    presses = press.positions.count * spec.repeats
    z_travel_mm = printer.safe_height_mm + spec.depth_mm
    motion_s = 2 * z_travel_mm / min(printer.z_feed_mm_s, printer.press_feed_mm_s)
    per_press_s = spec.hold_s + motion_s + 0.5  # the runner records 0.5 s beyond the press
    travel_s = math.hypot(printer.bed_x_mm, printer.bed_y_mm) / printer.travel_feed_mm_s
    samples = math.ceil(per_press_s * acq.rate_hz)
    per_press_bytes = samples * WAVEFORM_BYTES_PER_SAMPLE
    return ResourceEstimate(
        presses=presses,
        samples_per_press=samples,
        bytes_per_press=per_press_bytes,
        waveform_bytes=per_press_bytes * presses if waveforms else 0,
        rig_time_s=presses * (per_press_s + travel_s) + printer.homing_time_s,
    )


def _resource_problems(r: ResourceEstimate, press: Any, acq: AcquisitionSettings, source: str) -> list[Problem]:
    problems = []
    if r.samples_per_press > schema.MAX_SAMPLES_PER_PRESS:
        problems.append(
            Problem(
                f"one press would record {r.samples_per_press:.3g} samples ({r.bytes_per_press / 2**30:.3g} GiB), "
                f"beyond the cap of {schema.MAX_SAMPLES_PER_PRESS:.3g}",
                source,
                "press.hold_s",
                f"shorten press.hold_s ({press.press.hold_s:g} s) or lower acquisition.rate_hz ({acq.rate_hz:g} Hz)",
            )
        )
    if r.waveform_bytes > schema.MAX_WAVEFORM_BYTES:
        problems.append(
            Problem(
                f"the campaign would store {r.waveform_bytes / 2**30:.3g} GiB of waveforms, beyond the cap of "
                f"{schema.MAX_WAVEFORM_BYTES / 2**30:.0f} GiB",
                source,
                "record.waveforms",
                "set record.waveforms = false (features only), or fewer presses, a shorter hold or a lower rate",
            )
        )
    if r.rig_time_s > schema.MAX_RIG_TIME_S:
        problems.append(
            Problem(
                f"the campaign would take about {r.rig_time_s / 86400:.3g} days of rig time, beyond the cap of "
                f"{schema.MAX_RIG_TIME_S / 86400:.0f} days",
                source,
                "positions.count",
                "split it into several campaigns (fewer positions or repeats each), or shorten press.hold_s",
            )
        )
    return problems


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


def check_electrical(layout: Any, wiring: Any, excitation: Excitation, acq: AcquisitionSettings) -> ElectricalCheck:
    """Worst-case peak voltage: amplitude x (largest pair R_eq of the undeformed skin x press margin
    + 2 R_on + R_on mismatch), against the lowest of the mux rails, the compliance and the ADC's reach."""
    return electrical_check(
        layout,
        wiring.electrical,
        amplitude_a=excitation.amplitude_a,
        press_margin=excitation.press_margin,
        compliance_v=excitation.compliance_v,
        adc_range_v=acq.adc_range_v,
        voltage_gain=acq.voltage_gain,
    )


def electrical_check(
    layout: Any,
    electrical: schema.ElectricalTable,
    *,
    amplitude_a: float,
    press_margin: float,
    compliance_v: float,
    adc_range_v: float,
    voltage_gain: float,
) -> ElectricalCheck:
    """`check_electrical` on plain values: a layout, the mux chips' [electrical] limits and the excitation and ADC
    numbers (the design study calls it for each candidate skin, with the wiring it assumes)."""
    import numpy as np

    r_eq = np.asarray(equivalent_resistance(layout, 1.0 / layout.channel_resistance_ohm))
    # symmetric pairs tie up to rounding: name the first of them in pair order, whatever the solver's last bit
    k = int(np.argmax(np.round(r_eq / r_eq.max(), 9)))
    e = electrical
    path_ohm = float(r_eq[k]) * press_margin + 2 * e.r_on_ohm + e.r_on_mismatch_ohm
    limits = {
        f"mux supply rails ({e.supply_negative_v:g} V .. +{e.supply_positive_v:g} V)": min(
            e.supply_positive_v, -e.supply_negative_v
        ),
        "galvanostat compliance (excitation.compliance_v)": compliance_v,
        "ADC range over the voltage gain (acquisition.adc_range_v / voltage_gain)": adc_range_v / voltage_gain,
    }
    name = min(limits, key=lambda n: limits[n])
    return ElectricalCheck(layout.pairs[k].label, float(r_eq[k]), amplitude_a * path_ohm, limits[name], name)


CLIP_MESSAGE = "the excitation would clip"  # the refusal's opening (rig.railcheck adds its pressed figures)


def _electrical_problems(
    check: ElectricalCheck, layout: Any, wiring: Any, excitation: Excitation, source: str
) -> list[Problem]:
    if check.within_limit:
        return []
    e = wiring.electrical
    amp_max = excitation.amplitude_a * check.limit_v / check.peak_v
    return [
        Problem(
            f"{CLIP_MESSAGE}: {excitation.amplitude_a * 1e3:g} mA x ({check.largest_r_eq_ohm:.0f} ohm "
            f"(pair {check.largest_pair}, undeformed) x {excitation.press_margin:g} press margin + 2 x "
            f"{e.r_on_ohm:g} ohm R_on + {e.r_on_mismatch_ohm:g} ohm mismatch) = {check.peak_v:.3g} V peak, beyond "
            f"the {check.limit_name}: {check.limit_v:.3g} V",
            source,
            "excitation.amplitude_a",
            f"lower amplitude_a to <= {amp_max * 1e3:.3g} mA, or use a more conductive fluid (skin "
            f"resistivity_ohm_m = {layout.resistivity_ohm_m:g} ohm m in {_beside(layout.source, source)}), or other "
            "rails (wiring [electrical])",
        )
    ]


def _beside(path: str, protocol: str) -> str:
    """`path` as seen from the protocol's folder (`skins/paper.toml` for paper.toml's skin), else whole: a bare
    file name can be the protocol's own (paper.toml and skins/paper.toml)."""
    try:
        return Path(path).resolve().relative_to(Path(protocol).resolve().parent).as_posix()
    except ValueError:
        return str(path)


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

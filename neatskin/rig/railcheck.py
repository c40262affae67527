"""The pressed skin against the mux rails: how many of a protocol's presses would put some pair past the rails (or
the compliance, or the AI's reach) at a given current, through the protocol's own scene's skin model.

`campaign check`'s undeformed worst case (rig.protocol.electrical_check: the largest pair R_eq x press_margin) is
the refusal; a press can raise a pair's R_eq far beyond that margin (the finite-element pinch of the paper's skin
at 3.5 mm: up to 5.5x), and such a reading is clamped by the switch and flagged, recorded as a cut pair's (R =
inf; neatskin.acquisition.demod, pressvalues). This module counts them: the protocol's positions (its strategy
and seed) x its repeats at its depth, drawn as the forecast draws them (rig.simcampaign.pressed_skin: the scene's
placement error, depth jitter and drift; no measurement noise, which moves a reading by ~1e-4 of R), against the
DAQ's readable limit at each current (DaqConfig.readable_ohm). Pure in the pressed R; the skin is built once.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.errors import ConfigError, Problem
from neatskin.gcode.positions import generate_positions
from neatskin.rig.assembly import daq_config
from neatskin.rig.dryrig import dry_scene
from neatskin.rig.plan import Plan, build_plan
from neatskin.rig.protocol import CLIP_MESSAGE, CampaignProtocol, load_protocol
from neatskin.rig.simcampaign import pressed_skin
from neatskin.sim.dryscene import dry_skin


@dataclass(frozen=True)
class PressedRails:
    """A protocol's pressed readings against what the DAQ can read at one current."""

    amplitude_a: float
    readable_ohm: float  # DaqConfig.readable_ohm at this current
    rail_ohm: float  # rail_v / amplitude_a - 2 R_on - mismatch
    presses: int
    readings: int  # finite pressed readings (a pair already cut off by the pinch is not counted)
    presses_over: int  # presses with some finite reading at or beyond readable_ohm
    readings_over: int
    largest_ohm: float  # the largest finite pressed R_eq
    series_ohm: float

    @property
    def share(self) -> float:
        return self.presses_over / self.presses if self.presses else 0.0

    def summary(self, left: bool = False) -> str:
        """The line's figures; `left`: the presses are those a resume has left to press ("of the N left")."""
        peak_v = self.amplitude_a * (self.largest_ohm + self.series_ohm)
        presses = f"the {self.presses} left" if left else f"{self.presses} presses"
        if not self.presses_over:
            return (
                f"none of {presses} puts a pair past the rails at {self.amplitude_a * 1e3:g} mA (the "
                f"largest pressed R_eq {self.largest_ohm:.0f} ohm = {peak_v:.3g} V, {self.readable_ohm:.0f} ohm "
                "readable)"
            )
        return (
            f"{self.presses_over} of {presses} ({100 * self.share:.1f} %) put some pair past the "
            f"rails at {self.amplitude_a * 1e3:g} mA ({self.readings_over} of {self.readings} readings above "
            f"{self.readable_ohm:.0f} ohm; the largest pressed R_eq {self.largest_ohm:.0f} ohm = {peak_v:.3g} V): "
            "flagged clipped and recorded as a cut pair's (R = inf)"
        )


def pressed_resistance_ohm(protocol: CampaignProtocol, plan: Plan | None = None) -> np.ndarray:
    """(presses, pairs) pair R_eq of the protocol's presses through its dry run's skin, +inf for a pair cut off.
    `plan`: the protocol's, when the caller has built it (a dry run's, which its runner presses); else built here."""
    press = protocol.press
    xy = generate_positions(protocol.layout, press.positions).xy_mm
    # the plan once: the skin and the drift's interval read it
    dry = dry_scene(protocol, build_plan(protocol) if plan is None else plan)
    drawn = pressed_skin(
        protocol,
        xy,
        int(press.press.repeats),
        float(press.press.depth_mm),
        int(protocol.seed),
        skin=dry_skin(dry),  # simcampaign.skin_of's skin
        interval_s=dry.interval_s,  # simcampaign.press_interval_s's
    )
    return drawn.resistance_ohm


def pressed_rails(r_ohm: np.ndarray, config: DaqConfig, amplitude_a: float | None = None) -> PressedRails:
    """The pressed readings `r_ohm` (presses, pairs; +inf for a pair cut off) against `config` (at `amplitude_a`
    if given): a finite reading at or above its readable_ohm is one the rig flags and records as no value."""
    cfg = config if amplitude_a is None else dataclasses.replace(config, amplitude_a=float(amplitude_a))
    r = np.asarray(r_ohm, float)
    finite = np.isfinite(r)
    over = finite & (r >= cfg.readable_ohm)
    return PressedRails(
        amplitude_a=cfg.amplitude_a,
        readable_ohm=float(cfg.readable_ohm),
        rail_ohm=float(cfg.rail_ohm),
        presses=int(r.shape[0]),
        readings=int(finite.sum()),
        presses_over=int(over.any(axis=1).sum()),
        readings_over=int(over.sum()),
        largest_ohm=float(r[finite].max()) if finite.any() else 0.0,
        series_ohm=float(cfg.mux_series_ohm),
    )


def _where(protocol: CampaignProtocol) -> str:
    press = protocol.press
    return (
        f"{press.positions.count} positions x {press.press.repeats} at {press.press.depth_mm:g} mm through the "
        f"scene's {getattr(protocol.scene, 'deformation', '')} skin, as the forecast draws them"
    )


def pressed_rails_text(protocol: CampaignProtocol) -> str:
    """`campaign check`'s pressed line at the protocol's own current: a warning when some press passes the rails
    (the protocol is not refused: those readings are flagged and recorded as a cut pair's)."""
    return _line(protocol, pressed_rails(pressed_resistance_ohm(protocol), daq_config(protocol)))


def pressed_rails_warning(
    protocol: CampaignProtocol, plan: Plan | None = None, done_press_ids: Collection[int] | None = None
) -> str | None:
    """`campaign run`'s line before any motion: `campaign check`'s pressed line, word for word, when some press
    passes the rails; None when none does (a run prints nothing then). `plan`: the protocol's, if already built.
    `done_press_ids` (a resume: the presses on disk, `recorded_press_ids`): only the presses left are counted, and
    the line says "of the N left"; None when none of those passes the rails."""
    plan = build_plan(protocol) if plan is None else plan
    r_ohm = pressed_resistance_ohm(protocol, plan)
    if done_press_ids is not None:
        r_ohm = r_ohm[left_rows(plan, int(protocol.press.press.repeats), done_press_ids)]
    result = pressed_rails(r_ohm, daq_config(protocol))
    return _line(protocol, result, left=done_press_ids is not None) if result.presses_over else None


def left_rows(plan: Plan, repeats: int, done_press_ids: Collection[int]) -> np.ndarray:
    """The rows of `pressed_resistance_ohm` (position by position, `repeats` each) of the plan's presses whose id is
    not in `done_press_ids`: a press is its (position, repeat), whatever the press order."""
    left = plan.program.presses.excluding(done_press_ids)
    return np.array([b.position_id * repeats + b.repeat for b in left], dtype=np.int64)


def recorded_press_ids(folder: str | Path) -> set[int]:
    """The press ids a campaign folder holds on disk (its parts and consolidated file, read only): the presses a
    resume does not press again. A folder with none, or a file that cannot be read (the resume's own checks refuse
    it, with its fix), adds none."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from neatskin.datasets.reader import press_files
    from neatskin.errors import DataError

    try:
        files = press_files(folder)
    except DataError:
        return set()
    ids: set[int] = set()
    for file in files:
        try:
            ids.update(int(i) for i in pq.read_table(file, columns=["press_id"]).column("press_id").to_pylist())
        except (OSError, pa.ArrowException, KeyError):
            continue
    return ids


def _line(protocol: CampaignProtocol, result: PressedRails, left: bool = False) -> str:
    warning = "warning: " if result.presses_over else ""
    return f"electrical, pressed ({_where(protocol)}): {warning}{result.summary(left)}"


def with_pressed_figures(path: str | Path, problems: Sequence[Problem], solve_kernel: bool = True) -> list[Problem]:
    """The refusal (`campaign check`'s and `campaign run`'s) of a current whose undeformed worst case passes the
    rails, with the pressed figures at the current it suggests and at DaqConfig's default: the suggestion keeps the
    undeformed skin (x the press margin) inside the rails, not every pressed reading. Other problems, or a protocol
    that fails for another reason too, are returned as they are; so is the refusal when the figures would first
    need a pinch kernel solved and not solve_kernel (`campaign run`: minutes before one error line)."""
    refused = [p for p in problems if p.field == "excitation.amplitude_a" and p.message.startswith(CLIP_MESSAGE)]
    if len(refused) != 1 or len(problems) != 1:
        return list(problems)
    default_a = DaqConfig().amplitude_a
    try:
        protocol = load_protocol(path, amplitude_a=default_a)
        if not solve_kernel and missing_kernel(protocol):
            return list(problems)
        suggested_a = default_a * protocol.electrical.limit_v / protocol.electrical.peak_v
        r = pressed_resistance_ohm(protocol)
    except ConfigError:
        return list(problems)
    cfg = daq_config(protocol)
    at_suggested, at_default = pressed_rails(r, cfg, suggested_a), pressed_rails(r, cfg, default_a)
    p = refused[0]
    rest = p.fix.split(", or ", 1)[1] if p.fix and ", or " in p.fix else None
    at_default_text = (
        f"{_share(at_default)} put some pair past the rails, flagged and recorded as a cut pair's"
        if at_default.presses_over
        else f"none of {at_default.presses} presses puts a pair past the rails"
    )
    fix = (
        f"lower amplitude_a to {default_a * 1e3:g} mA (the default: pressed ({_where(protocol)}), {at_default_text}); "
        f"{suggested_a * 1e3:.3g} mA is the most that keeps the undeformed skin x the press margin inside them, "
        f"where {_share(at_suggested)} would"
    )
    return [Problem(p.message, p.file, p.field, f"{fix}, or {rest}" if rest else fix)]


def _share(result: PressedRails) -> str:
    return (
        f"{result.presses_over} of {result.presses} presses ({100 * result.share:.1f} %; "
        f"{result.readings_over} of {result.readings} readings)"
    )


def missing_kernel(protocol: CampaignProtocol) -> str | None:
    """Why the forecast would first have to solve the scene's finite-element pinch kernel (minutes of CPU: a probe
    or geometry with no kernel packaged or cached), or None. A real run's forecast does not solve it: the run would
    wait for it before any motion (`campaign check` solves it once and caches it)."""
    scene = protocol.scene
    if getattr(scene, "deformation", "parametric") != "fe-kernel" or scene.fidelity != "deformation":
        return None
    from neatskin.skin.kernel import KernelSpec, load_kernel

    try:
        load_kernel(KernelSpec.for_layout(protocol.layout, protocol.press.press.probe_diameter_mm / 2), compute=False)
    except FileNotFoundError:
        return "no pinch kernel solved yet for this skin and probe"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m neatskin.rig.railcheck PROTOCOL`: the pressed-rails warning line, or nothing (a real `campaign
    run` asks this child, so that its own process builds no simulator). PROTOCOL may be a campaign folder: its
    recorded protocol and files (`inputs/`, as `campaign resume` runs them), and only the presses not on disk yet
    (the line says "of the N left"). A bad protocol: its error, exit 3; a pinch kernel it would first have to
    solve: exit 5."""
    import os
    import sys

    from neatskin.errors import ExitCode
    from neatskin.orphans import end_with_parent

    end_with_parent(os.getppid())  # a run killed outright (or signalled alone) leaves no forecast running
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m neatskin.rig.railcheck PROTOCOL", file=sys.stderr)
        return int(ExitCode.USAGE)
    try:
        protocol = _load(Path(args[0]))
        missing = missing_kernel(protocol)
        if missing:
            print(missing, file=sys.stderr)
            return int(ExitCode.DATA)
        done = recorded_press_ids(args[0]) if Path(args[0]).is_dir() else None  # a resume: the presses left
        warning = pressed_rails_warning(protocol, done_press_ids=done)
    except ConfigError as exc:
        print(str(exc).replace("\n", " "), file=sys.stderr)
        return int(ExitCode.CONFIG)
    if warning:
        print(warning)
    return 0


def _load(path: Path) -> CampaignProtocol:
    """A protocol file, or a campaign folder's recorded protocol (what `campaign resume` runs)."""
    if path.is_dir():
        from neatskin.rig.folder import load_inputs

        return load_inputs(path)
    return load_protocol(path)


if __name__ == "__main__":
    raise SystemExit(main())

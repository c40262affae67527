"""The `neatskin printer send` command: stream a G-code file to a printer through the driver, and stop safely.

Ctrl-C (SIGINT), SIGTERM or SIGHUP stops after the line in flight: nothing queued is sent, the probe is lifted when
it may be down (the lift rule is in `lift_lines`, its height in `travel_height_mm`), and the last
acknowledged line of the file is printed with the exact command that continues from the next one
(`--from-line N`), so no line runs twice. The lift is checked with M114: "lifted" is said only
when the firmware reports the probe at or above the height, and never below the skin surface.
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neatskin.cligroups import add_connect_timeout, add_quiet, command_group
from neatskin.stopsignals import as_ctrl_c

DEFAULT_SAFE_Z_MM = 5.0  # without a profile or a Z of the program's own: the height taken to be clear


def register(subparsers: Any) -> None:
    host = command_group(subparsers, "printer", "talk to a Marlin printer over a serial port")
    send = host.add_parser(
        "send",
        help="stream a G-code file to a printer, exactly once per line, with progress",
        description="Stream a G-code file through the Marlin driver (line numbers, checksums, resends, "
        "lost-ok recovery). Stops with a clear error naming the last line the printer acknowledged. "
        "Ctrl-C stops after the line in flight, lifts the probe if it may be down, and prints the "
        "command that continues from the next line (--from-line).",
    )
    send.add_argument("file", help="G-code file")
    send.add_argument(
        "--port", required=True, help="serial port or pyserial URL (/dev/ttyUSB0, /dev/pts/3, socket://h:p)"
    )
    send.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    send.add_argument(
        "--profile",
        default=None,
        help="printer profile TOML: every move checked against its bed and soft limits before anything is sent "
        "(as gcode check --profile), and deadlines sized from the motion",
    )
    send.add_argument("--wire-log", default=None, help="append a timestamped log of every byte to this file")
    add_connect_timeout(send, 3.0, "seconds to wait for the printer's boot banner, `start` (default 3)")
    add_quiet(send)
    send.add_argument(
        "--from-line",
        type=int,
        default=1,
        metavar="N",
        help="start at line N of the file (1-based; what an interrupted send prints to continue)",
    )
    send.add_argument(
        "--safe-z-mm",
        type=float,
        default=None,
        help="on Ctrl-C, lift to this printer Z (default: the highest Z the program commanded so far, and "
        "with --profile at least the profile's safe_height_mm above its calibrated surface; "
        f"else {DEFAULT_SAFE_Z_MM:g})",
    )
    send.set_defaults(handler=printer_send_handler)


@dataclass(frozen=True)
class Lift:
    """The relative lift after an interrupt: the lines, and why (or why not)."""

    lines: tuple[str, ...]
    reason: str


def travel_height_mm(lines: list[str], profile: Any | None) -> float | None:
    """The height a lift goes to: the highest Z these lines commanded (the program's own travel height),
    and with a profile at least its safe height above the calibrated surface; None when neither is known."""
    from neatskin.errors import ConfigError
    from neatskin.gcode.machine import Machine
    from neatskin.gcode.parse import parse_line

    machine = Machine(profile)
    top: float | None = None
    for text in lines:
        try:
            line = parse_line(text)
        except ConfigError:
            continue
        if line is None:
            continue
        machine.step(line)
        z = machine.logical_mm[2]
        if z is not None and (top is None or z > top):
            top = z
    if profile is not None:
        above = profile.calibration.surface_z_mm + profile.safe_height_mm
        top = above if top is None else max(top, above)
    if top is not None and profile is not None:
        top = min(top, profile.soft_max_mm.z)
    return top


def lift_lines(
    z_mm: float | None, safe_z_mm: float, *, max_z_mm: float | None, feed_mm_s: float, absolute: bool
) -> Lift:
    """The rule: lift only when the probe may be down, i.e. the commanded Z after the last acknowledged
    line is unknown or below the travel height safe_z_mm; lift by the distance to it (the whole of it
    when Z is unknown), never past the soft maximum; relative (`G91`, `G0 Z+d`), then back to the
    file's own distance mode."""
    if z_mm is not None and z_mm >= safe_z_mm:
        return Lift((), f"no lift: Z {z_mm:g} mm is at or above the travel height {safe_z_mm:g} mm")
    rise = safe_z_mm if z_mm is None else safe_z_mm - z_mm
    if max_z_mm is not None and z_mm is not None:
        rise = min(rise, max_z_mm - z_mm)
    if rise <= 0:
        return Lift((), f"no lift: Z {z_mm:g} mm is at the top of the travel")
    where = "unknown" if z_mm is None else f"{z_mm:g} mm"
    restore = "G90" if absolute else "G91"
    lines = ("G91", f"G0 Z{rise:.3f} F{feed_mm_s * 60:.0f}", restore)
    return Lift(lines, f"lifted the probe by {rise:.3f} mm (Z was {where}, travel height {safe_z_mm:g} mm)")


@as_ctrl_c()  # SIGTERM, SIGHUP: as Ctrl-C (stop after the line in flight, lift)
def printer_send_handler(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from neatskin.errors import ConfigError, Problem
    from neatskin.gcode.bounds import firmware_text_problem
    from neatskin.gcode.parse import parse_numbered
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.marlin.driver import DriverConfig, MarlinDriver

    path = Path(args.file)
    try:
        text = path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read G-code: {exc}", file=path, fix="give a readable ASCII G-code file") from exc
    # a syntax error, or a line the firmware would not run as written (lower case, too long), is reported before
    # the port is touched: on the board a long numbered line fails its checksum on every resend
    parsed = parse_numbered(text, source=str(path))
    refused = [
        Problem(what, str(path), f"line {number}", fix)
        for number, line in parsed
        if (problem := firmware_text_problem(line)) is not None
        for what, fix in [problem]
    ]
    if refused:
        raise ConfigError(problems=refused)
    profile = load_printer_profile(args.profile) if args.profile else None
    if profile is not None:  # SPEC: a move outside the bed or the soft limits is refused before anything is sent
        _refuse_moves_outside(profile, args.profile, parsed, path, args.from_line)
    all_lines = text.splitlines()
    if not 1 <= args.from_line <= len(all_lines) + 1:
        raise ConfigError(
            f"--from-line {args.from_line} is outside the file (lines 1 to {len(all_lines)})",
            file=path,
            field="--from-line",
            fix="give a line number the interrupted send printed",
        )
    numbered = [
        (number, line)
        for number, line in enumerate(all_lines, start=1)
        if number >= args.from_line and line.split(";", 1)[0].strip()
    ]
    config = DriverConfig(boot_timeout_s=args.connect_timeout_s, confirm_batches=True)
    driver = MarlinDriver.open(args.port, args.baud, config=config, profile=profile, wire_log=args.wire_log)
    bar = tqdm(total=0, unit="line", disable=args.quiet, file=sys.stderr)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        driver.connect()
        try:
            sent = driver.send_lines([line for _, line in numbered], progress=progress, source=str(path))
        except KeyboardInterrupt:
            bar.close()
            return _interrupted(args, driver, numbered, profile)
    finally:
        bar.close()
        driver.close()
    stats = driver.stats
    print(
        f"sent {sent} lines to {args.port}: {stats['lines_resent']} resent, {stats['probes']} lost-ok probes, "
        f"{stats['busy']} busy keep-alives"
    )
    return 0


def _refuse_moves_outside(profile: Any, profile_arg: str, parsed: Any, path: Path, from_line: int) -> None:
    """`gcode check --profile`'s bounds check (gcode.bounds.check_moves, on the whole file: the position a line
    starts from depends on every line before it), refusing what lies in the lines this send would stream: one
    CheckFailed (exit 1, as `gcode check`) naming the file, each line and the fix; the port is not opened."""
    from neatskin.errors import CheckFailed
    from neatskin.gcode.bounds import check_moves

    numbers = [number for number, _ in parsed]
    problems = check_moves(profile, [line for _, line in parsed], str(path), numbers)
    sent = [p for p in problems if p.field is None or int(p.field.split()[-1]) >= from_line]
    if sent:
        fixed = [
            dataclasses.replace(
                p,
                fix=f"{p.fix}, or give --profile the profile of the printer the file is for "
                f"(check with: neatskin gcode check {path} --profile {profile_arg})",
            )
            for p in sent
        ]
        raise CheckFailed(problems=fixed)


def _interrupted(args: argparse.Namespace, driver: Any, numbered: list[tuple[int, str]], profile: Any) -> int:
    """Ctrl-C: stop after the line in flight, lift if the probe may be down, say where to continue."""
    from neatskin.marlin.errors import MarlinError

    err = sys.stderr
    print("interrupted: sending nothing more; waiting for the line in flight", file=err, flush=True)
    acked = driver.stop_after_line_in_flight(timeout_s=60.0)
    if acked:
        number, line = numbered[acked - 1]
        print(f"the printer acknowledged line {number} of {args.file}: {line.strip()!r}", file=err)
    else:
        print(f"the printer acknowledged no line of {args.file} in this run", file=err)
    # the line in flight never got its ok (the printer failed, or it is still running): it may have run
    in_doubt = driver.failure is not None or driver.lines_in_flight > 0
    safe_z = args.safe_z_mm
    if safe_z is None:
        sent = acked + driver.lines_in_flight  # a line in flight may have moved too
        safe_z = travel_height_mm([line for _, line in numbered[:sent]], profile)
    if safe_z is None:
        safe_z = DEFAULT_SAFE_Z_MM
    surface = profile.calibration.surface_z_mm if profile is not None else None
    _, _, z_mm = driver.commanded_position_mm
    lift = lift_lines(
        z_mm,
        safe_z,
        max_z_mm=profile.soft_max_mm.z if profile is not None else None,
        feed_mm_s=profile.z_feed_mm_s if profile is not None else 5.0,
        absolute=driver.commanded_absolute,
    )
    try:
        if lift.lines and driver.lines_in_flight:
            lift = Lift((), "no lift: a line is still in flight; lift the probe by hand before continuing")
        if lift.lines:
            driver.send_lines([*lift.lines, "M400"], source="lift")
            reported = driver.position().z_mm  # the firmware's word, not the host's model
            done = f" ({' / '.join(lift.lines)}); the printer reports Z {reported:g} mm"
            if surface is not None and reported < surface:
                print(f"the probe is still below the skin surface (Z {surface:g} mm){done}: lift it by hand", file=err)
            elif reported < safe_z - 1e-3:
                print(
                    f"the probe rose only to Z {reported:g} mm, below the travel height {safe_z:g} mm{done}", file=err
                )
            else:
                print(lift.reason + done, file=err)
        else:
            print(lift.reason, file=err)
    except MarlinError as exc:
        print(f"could not lift the probe: {exc}", file=err)
    next_line = numbered[acked][0] if acked < len(numbered) else None
    if next_line is None:
        print("every line of the file was acknowledged: nothing to continue", file=err)
        return 130
    command = ["neatskin", "printer", "send", "--port", args.port]
    if args.baud != 115200:
        command += ["--baud", str(args.baud)]
    if args.profile:
        command += ["--profile", args.profile]
    command += ["--from-line", str(next_line), args.file]
    if in_doubt:
        print(f"line {next_line} may have run: check the printer before continuing", file=err)
    print(f"continue with: {shlex.join(command)}", file=err, flush=True)
    return 130

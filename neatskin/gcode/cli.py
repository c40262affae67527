"""`neatskin gcode ...`: generate a press program from a protocol, check a G-code file, fit a calibration.

A thin layer over neatskin.gcode.spec, .parse, .bounds, .motion and .calibration.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from neatskin.cligroups import add_out
from neatskin.errors import CheckFailed, ConfigError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "gcode", help="press positions, press programs and Marlin G-code", description=__doc__.splitlines()[0]
    )
    sub = parser.add_subparsers(dest="gcode_command", metavar="ACTION", required=True)

    gen = sub.add_parser("generate", help="write the press program of a protocol as G-code")
    gen.add_argument("protocol", type=Path, help="protocol TOML (e.g. protocols/paper.toml)")
    add_out(gen, "G-code file to write", required=True)
    gen.add_argument(
        "--no-hold", action="store_true", help="leave out the G4 hold (the runner's acquisition is the hold)"
    )
    gen.add_argument(
        "--positions",
        type=Path,
        metavar="FILE.csv",
        help="also write the positions (position_id, x_mm, y_mm, feature; sensor frame) as CSV",
    )
    gen.add_argument("--plot", type=Path, metavar="FILE.png", help="also draw the positions on the layout as PNG")
    gen.set_defaults(handler=_generate)

    chk = sub.add_parser("check", help="parse a G-code file; with a profile, check bounds and estimate its time")
    chk.add_argument("file", type=Path, help="G-code file")
    chk.add_argument("--profile", type=Path, help="printer profile TOML (e.g. protocols/printers/paper.toml)")
    chk.set_defaults(handler=_check)

    cal = sub.add_parser("calibrate", help="fit sensor->printer offset, rotation and surface height")
    cal.add_argument(
        "--point",
        action="append",
        required=True,
        metavar="SX,SY,PX,PY,PZ",
        help="a reference point: sensor x,y (mm) and the printer x,y,z (M114) with the probe touching it; give 2 or 3",
    )
    cal.set_defaults(handler=_calibrate)


def _generate(args: argparse.Namespace) -> int:
    from neatskin.gcode.emit import check_output_path, program_lines, write_lines_atomic, write_text_atomic
    from neatskin.gcode.motion import estimate_program_time
    from neatskin.gcode.spec import build_from_protocol

    for path, option in ((args.out, "--out"), (args.positions, "--positions"), (args.plot, "--plot")):
        if path is not None:
            check_output_path(path, option)
    program, layout, profile = build_from_protocol(args.protocol, hold_in_gcode=not args.no_hold)
    n_lines = write_lines_atomic(args.out, program_lines(program), "ascii", "--out")  # never held whole
    if args.positions is not None:
        ps = program.positions
        rows = ["position_id,x_mm,y_mm,feature"] + [
            f"{i},{x:.3f},{y:.3f},{f}" for i, x, y, f in zip(ps.ids, ps.x_mm, ps.y_mm, ps.features)
        ]
        write_text_atomic(args.positions, "\n".join(rows) + "\n", "utf-8", "--positions")
    if args.plot is not None:
        from neatskin.gcode.plot import plot_positions

        visits = program.presses.position_ids.tolist()
        route = [p for k, p in enumerate(visits) if k == 0 or p != visits[k - 1]]
        try:
            plot_positions(
                layout,
                program.positions,
                args.plot,
                route=route if program.route_unordered_mm else None,
                title=f"{program.name}: {len(program.positions)} positions, seed {program.seed}",
            )
        except OSError as exc:
            raise ConfigError(
                f"cannot write the plot: {exc.strerror or exc}",
                file=str(args.plot),
                field="--plot",
                fix="give --plot a writable .png path",
            ) from exc
    estimate = estimate_program_time(program.command_lines(), profile)
    print(f"wrote {args.out}: {len(program.positions)} positions, {len(program.presses)} presses, {n_lines} lines")
    print(
        f"estimated printer time: {_hms(estimate.total_s)} (motion {_hms(estimate.motion_s)}, "
        f"dwell {_hms(estimate.dwell_s)}, homing {_hms(estimate.homing_s)})"
    )
    if program.route_unordered_mm is not None:
        saved = program.route_unordered_mm - program.route_mm
        print(
            f"travel ordering: route {program.route_mm:.1f} mm instead of {program.route_unordered_mm:.1f} mm "
            f"({saved:.1f} mm, {100 * saved / max(program.route_unordered_mm, 1e-9):.0f} % shorter)"
        )
    return 0


def _check(args: argparse.Namespace) -> int:
    from neatskin.gcode.bounds import check_commands, check_moves, check_phases
    from neatskin.gcode.motion import estimate_program_time
    from neatskin.gcode.parse import parse_numbered, read_program_file
    from neatskin.gcode.profile import load_printer_profile

    source = str(args.file)
    # the profile first: a wrong --profile is one error before anything is printed
    profile = load_printer_profile(args.profile) if args.profile is not None else None
    try:
        numbered = parse_numbered(read_program_file(args.file), source=source)
    except ConfigError as exc:  # the file checked is not G-code a printer would take: the check's verdict
        raise CheckFailed(problems=exc.problems) from exc
    if not numbered:
        raise CheckFailed(
            "holds no G-code command (empty, or comments only): not a press program",
            file=source,
            fix="give the .gcode file written by `neatskin gcode generate`",
        )
    numbers = [n for n, _ in numbered]
    lines = [line for _, line in numbered]
    codes: dict[str, int] = {}
    for line in lines:
        codes[line.code] = codes.get(line.code, 0) + 1
    presses = sum(
        1
        for line in lines
        if line.code == "M118" and line.text.startswith("NS ") and line.text.endswith(" phase=press")
    )
    print(
        f"{args.file}: {len(lines)} commands, {presses} presses, "
        + ", ".join(f"{code} x{n}" for code, n in sorted(codes.items()))
    )
    problems = check_commands(lines, source, numbers) + check_phases(lines, source, numbers)
    if profile is None:
        print("no --profile given: bounds and time not checked")
        if problems:
            raise CheckFailed(problems=problems)
        return 0
    problems = check_moves(profile, lines, source, numbers) + problems
    estimate = estimate_program_time(lines, profile)
    print(
        f"estimated printer time on {profile.name}: {_hms(estimate.total_s)} ({estimate.moves} moves, "
        f"{estimate.path_mm / 1000:.1f} m of path)"
    )
    if problems:  # printed by neatskin.cli, one line per problem, exit status 1
        raise CheckFailed(problems=problems)
    print(
        "bounds: every move inside the bed and the soft limits, feeds within the maxima; "
        "every marked phase ends in M400; only press-program commands (no EEPROM, heater or M112)"
    )
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from neatskin.gcode.calibration import fit_calibration

    sensor, printer = [], []
    for k, text in enumerate(args.point):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 5:
            raise ConfigError(
                f"point {text!r} is not 5 numbers",
                field=f"--point[{k}]",
                fix="write SX,SY,PX,PY,PZ, e.g. --point 0,0,95.2,94.8,5.6",
            )
        sensor.append(values[:2])
        printer.append(values[2:])
    fit = fit_calibration(sensor, printer, source="--point")
    c = fit.calibration
    print("[calibration]")
    print(
        f"offset_x_mm = {c.offset_x_mm:.3f}\noffset_y_mm = {c.offset_y_mm:.3f}\n"
        f"rotation_deg = {c.rotation_deg:.4f}\nsurface_z_mm = {c.surface_z_mm:.3f}"
    )
    print(
        f"# residual: rms {fit.rms_mm:.3f} mm, max {fit.max_mm:.3f} mm (xy); surface z spread {fit.z_spread_mm:.3f} mm"
    )
    return 0


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}h{(s % 3600) // 60:02d}m{s % 60:02d}s"

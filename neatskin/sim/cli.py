"""The `neatskin sim printer` command: the simulated Marlin printer on a pseudo-terminal, for any host program."""

from __future__ import annotations

import argparse
import sys

from neatskin.cligroups import command_group, positive_finite

DEFAULT_PROFILE = "protocols/printers/paper.toml"


def register(subparsers) -> None:
    sim = command_group(subparsers, "sim", "simulated hardware, served for any host program")
    printer = sim.add_parser(
        "printer",
        help="serve a simulated Marlin printer on a pseudo-terminal",
        description="Start a simulated Marlin printer on a new pseudo-terminal, print its device path as the "
        "first line, and serve until interrupted (Ctrl-C). Point any host at the path. After M112 it is halted "
        "until a host reopens the port (pyserial's open resets it, as a board's auto-reset does) or it gets "
        "SIGUSR1 (kill -USR1 <pid>); then it boots again (`start`, unhomed).",
    )
    printer.add_argument("--profile", default=DEFAULT_PROFILE, help=f"printer profile TOML (default {DEFAULT_PROFILE})")
    printer.add_argument("--seed", type=int, default=0, help="seed of the injected faults")
    printer.add_argument(
        "--faults",
        default="",
        help="none, noisy, realistic, extreme, or key=value,... "
        "(corrupt, drop_line, drop_ok, duplicate, busy_storm, reset_after, dead_after, dead_closes). "
        "Hosts without lost-line recovery (Printrun, OctoPrint) stall on drop_line and drop_ok, which realistic "
        "and extreme include: give them noisy (corrupted lines, answered by Resend:, and busy storms)",
    )
    printer.add_argument(
        "--time",
        choices=("scaled", "virtual"),
        default="scaled",
        help="scaled: real time x --speed (default); virtual: no waiting, the clock jumps",
    )
    printer.add_argument("--speed", type=positive_finite, default=1.0, help="time scale of --time scaled (default 1)")
    printer.add_argument("--advanced-ok", action="store_true", help="answer `ok N.. P.. B..` (ADVANCED_OK)")
    printer.add_argument(
        "--no-motion-before-homing",
        action="store_true",
        help="refuse G0/G1 until every axis is homed (`echo:Home XYZ First`), as Marlin built with "
        "NO_MOTION_BEFORE_HOMING; by default it moves from where it believes it is, as stock Marlin",
    )
    printer.set_defaults(handler=sim_printer_handler)


def sim_printer_handler(args: argparse.Namespace) -> int:
    import time

    from neatskin.gcode.profile import load_printer_profile
    from neatskin.sim.faults import FaultConfig
    from neatskin.sim.printer import SimulatedPrinter

    faults = FaultConfig.parse(args.faults)
    profile = load_printer_profile(args.profile)
    sim = SimulatedPrinter(
        profile,
        seed=args.seed,
        faults=faults,
        time_mode=args.time,
        speed=args.speed,
        advanced_ok=args.advanced_ok,
        no_motion_before_homing=args.no_motion_before_homing,
    )
    path = sim.start_pty()
    print(path, flush=True)
    print(
        f"simulated Marlin printer ({profile.name}, faults: {args.faults or 'none'}) on {path}; Ctrl-C stops it",
        file=sys.stderr,
        flush=True,
    )
    import signal

    signal.signal(signal.SIGUSR1, lambda *_: sim.reset())  # the reset button, for a host that cannot reopen the port
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
        print(f"stopped after {sim.executed_count} commands", file=sys.stderr)
    return 0

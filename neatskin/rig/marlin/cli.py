"""The `neatskin sim printer` and `neatskin printer send` commands: the simulated printer on a pty, and streaming G-code."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_PROFILE = "protocols/printers/paper.toml"


def _group(subparsers, name: str, help_text: str):
    """The sub-command action of group `name`, created or (if another component made it) reused."""
    parser = subparsers.choices.get(name) if hasattr(subparsers, "choices") else None
    if parser is None:
        parser = subparsers.add_parser(name, help=help_text, description=help_text)
        return parser.add_subparsers(dest=f"{name}_command", metavar=f"{name.upper()}_COMMAND", required=True)
    for action in parser._actions:  # noqa: SLF001 - argparse keeps no public handle on it
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            return action
    return parser.add_subparsers(dest=f"{name}_command", required=True)


def register(subparsers) -> None:
    sim = _group(subparsers, "sim", "simulated hardware, served for any host program")
    printer = sim.add_parser(
        "printer", help="serve a simulated Marlin printer on a pseudo-terminal",
        description="Start a simulated Marlin printer on a new pseudo-terminal, print its device path as the "
                    "first line, and serve until interrupted (Ctrl-C). Point any host at the path.")
    printer.add_argument("--profile", default=DEFAULT_PROFILE, help=f"printer profile TOML (default {DEFAULT_PROFILE})")
    printer.add_argument("--seed", type=int, default=0, help="seed of the injected faults")
    printer.add_argument("--faults", default="", help="none, realistic, extreme, or key=value,... "
                         "(corrupt, drop_line, drop_ok, duplicate, busy_storm, reset_after, dead_after, dead_closes)")
    printer.add_argument("--time", choices=("scaled", "virtual"), default="scaled",
                         help="scaled: real time x --speed (default); virtual: no waiting, the clock jumps")
    printer.add_argument("--speed", type=float, default=1.0, help="time scale of --time scaled (default 1)")
    printer.add_argument("--advanced-ok", action="store_true", help="answer `ok N.. P.. B..` (ADVANCED_OK)")
    printer.set_defaults(handler=sim_printer_handler)

    host = _group(subparsers, "printer", "talk to a Marlin printer over a serial port")
    send = host.add_parser(
        "send", help="stream a G-code file to a printer, exactly once per line, with progress",
        description="Stream a G-code file through the Marlin driver (line numbers, checksums, resends, "
                    "lost-ok recovery). Stops with a clear error naming the last line the printer acknowledged.")
    send.add_argument("file", help="G-code file")
    send.add_argument("--port", required=True, help="serial port or pyserial URL (/dev/ttyUSB0, /dev/pts/3, socket://h:p)")
    send.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    send.add_argument("--profile", default=None, help="printer profile TOML, to size deadlines from the motion")
    send.add_argument("--wire-log", default=None, help="append a timestamped log of every byte to this file")
    send.add_argument("--boot-timeout-s", type=float, default=3.0, help="wait this long for `start` (default 3)")
    send.add_argument("--no-progress", action="store_true", help="no progress bar")
    send.set_defaults(handler=printer_send_handler)


def sim_printer_handler(args: argparse.Namespace) -> int:
    import time

    from neatskin.gcode.profile import load_printer_profile
    from neatskin.rig.marlin.faults import FaultConfig
    from neatskin.rig.marlin.simprinter import SimulatedPrinter

    faults = FaultConfig.parse(args.faults)
    profile = load_printer_profile(args.profile)
    sim = SimulatedPrinter(profile, seed=args.seed, faults=faults, time_mode=args.time, speed=args.speed,
                           advanced_ok=args.advanced_ok)
    path = sim.start_pty()
    print(path, flush=True)
    print(f"simulated Marlin printer ({profile.name}, faults: {args.faults or 'none'}) on {path}; Ctrl-C stops it",
          file=sys.stderr, flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
        print(f"stopped after {len(sim.executed)} commands", file=sys.stderr)
    return 0


def printer_send_handler(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from neatskin.errors import ConfigError
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.rig.marlin.driver import DriverConfig, MarlinDriver

    path = Path(args.file)
    try:
        text = path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read G-code: {exc}", file=path, fix="give a readable ASCII G-code file") from exc
    from neatskin.gcode.parse import parse_program

    parse_program(text, source=str(path))  # a syntax error is reported before the port is touched
    profile = load_printer_profile(args.profile) if args.profile else None
    config = DriverConfig(boot_timeout_s=args.boot_timeout_s)
    driver = MarlinDriver.open(args.port, args.baud, config=config, profile=profile, wire_log=args.wire_log)
    bar = tqdm(total=0, unit="line", disable=args.no_progress, file=sys.stderr)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        driver.connect()
        sent = driver.send_lines(text.splitlines(), progress=progress, source=str(path))
    finally:
        bar.close()
        driver.close()
    stats = driver.stats
    print(f"sent {sent} lines to {args.port}: {stats['lines_resent']} resent, {stats['probes']} lost-ok probes, "
          f"{stats['busy']} busy keep-alives")
    return 0

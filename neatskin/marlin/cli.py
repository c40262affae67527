"""The `neatskin printer send` command: stream a G-code file to a printer through the driver."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from neatskin.cligroups import command_group


def register(subparsers) -> None:
    host = command_group(subparsers, "printer", "talk to a Marlin printer over a serial port")
    send = host.add_parser(
        "send",
        help="stream a G-code file to a printer, exactly once per line, with progress",
        description="Stream a G-code file through the Marlin driver (line numbers, checksums, resends, "
        "lost-ok recovery). Stops with a clear error naming the last line the printer acknowledged.",
    )
    send.add_argument("file", help="G-code file")
    send.add_argument(
        "--port", required=True, help="serial port or pyserial URL (/dev/ttyUSB0, /dev/pts/3, socket://h:p)"
    )
    send.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    send.add_argument("--profile", default=None, help="printer profile TOML, to size deadlines from the motion")
    send.add_argument("--wire-log", default=None, help="append a timestamped log of every byte to this file")
    send.add_argument("--boot-timeout-s", type=float, default=3.0, help="wait this long for `start` (default 3)")
    send.add_argument("--no-progress", action="store_true", help="no progress bar")
    send.set_defaults(handler=printer_send_handler)


def printer_send_handler(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from neatskin.errors import ConfigError
    from neatskin.gcode.profile import load_printer_profile
    from neatskin.marlin.driver import DriverConfig, MarlinDriver

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
    print(
        f"sent {sent} lines to {args.port}: {stats['lines_resent']} resent, {stats['probes']} lost-ok probes, "
        f"{stats['busy']} busy keep-alives"
    )
    return 0

"""`neatskin monitor`, `neatskin campaign pause|continue|stop` and `neatskin printer console`: thin layers over
neatskin.monitor.server, neatskin.rig.control and neatskin.monitor.console."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from neatskin.cligroups import add_connect_timeout, command_group, tcp_port


def register(subparsers) -> None:
    monitor = subparsers.add_parser(
        "monitor",
        help="a live local web page of a campaign folder (running, killed or finished)",
        description="Serve a live page of CAMPAIGN_DIR on 127.0.0.1; prints the control token for pause/stop.",
    )
    monitor.add_argument("folder", type=Path, metavar="CAMPAIGN_DIR", help="the campaign folder to show")
    monitor.add_argument("--port", type=tcp_port, default=8765, help="TCP port (default 8765; 0 picks a free one)")
    monitor.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1, this machine only)")
    monitor.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow binding to an address other than loopback (anyone who can reach it sees the page)",
    )
    monitor.add_argument(
        "--token", help="control token instead of a random one (other users can read it in the process list)"
    )
    monitor.add_argument("--read-only", action="store_true", help="no controls at all, not even with a token")
    monitor.add_argument(
        "--printer-port",
        metavar="PORT",
        help="the page's printer terminal sends lines to this port (with the token), only while no campaign "
        "holds the folder",
    )
    monitor.set_defaults(handler=_monitor)

    campaign = command_group(subparsers, "campaign", "run, resume or check a press campaign")
    for action, text in (
        ("pause", "pause a running campaign at the next safe point (the probe lifts and waits)"),
        ("continue", "continue a paused campaign"),
        ("stop", "stop at the next safe point: the probe lifts and parks; `campaign resume` finishes it"),
    ):
        sub = campaign.add_parser(action, help=text, description=text[0].upper() + text[1:] + ".")
        sub.add_argument("folder", type=Path, metavar="DIR", help="the running campaign's folder")
        sub.set_defaults(handler=_control, control_action=action)

    printer = command_group(subparsers, "printer", "talk to the printer over its serial port")
    console = printer.add_parser(
        "console",
        help="interactive console: history, jog keys, M114/M119, calibration points",
        description="An interactive Marlin console (prompt_toolkit); type `help` inside it.",
    )
    console.add_argument("--port", required=True, help="serial port or pty, e.g. /dev/ttyUSB0")
    console.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    add_connect_timeout(console, 5.0, "seconds to wait for the printer's boot banner (default 5)")
    console.add_argument(
        "--history", type=Path, default=None, help="history file (default ~/.neatskin_console_history)"
    )
    console.add_argument("--calibration-out", type=Path, default=None, help="file the `save` command writes")
    console.set_defaults(handler=_console)


def _monitor(args: argparse.Namespace) -> int:
    from neatskin.monitor.server import serve

    serve(
        args.folder,
        host=args.host,
        port=args.port,
        allow_remote=args.allow_remote,
        token=args.token,
        read_only=args.read_only,
        printer_port=args.printer_port,
        announce=print,
    )
    return 0


CONTROL_WAIT_S = 10.0  # how long `campaign pause DIR` waits for a starting run's manifest.json


def _control(args: argparse.Namespace) -> int:
    from neatskin.datasets.manifest import read_manifest
    from neatskin.errors import DataError
    from neatskin.rig.control import read_state, request_control

    request_control(args.folder, args.control_action, by="cli", wait_s=CONTROL_WAIT_S)  # a run starting: kept
    try:
        status = read_manifest(args.folder).get("status")
    except DataError as exc:  # the request is recorded (the runner reads it, not the manifest): say so, and why
        status = "unknown"
        for problem in exc.problems:
            print(f"neatskin: warning: {problem}", file=sys.stderr)
    state = read_state(args.folder).get("state", "unknown")
    print(f"{args.control_action} requested for {args.folder} (campaign {status}, runner {state})")
    if status not in ("running", "unknown"):
        print(f"  the campaign is not running; to finish it: neatskin campaign resume {args.folder}")
    elif args.control_action in ("pause", "stop"):
        print("  the runner acts on it after the press in flight")
    return 0


def _console(args: argparse.Namespace) -> int:
    from neatskin.monitor.console import run_console

    return run_console(
        args.port,
        baud_rate=args.baud,
        connect_timeout_s=args.connect_timeout_s,
        history_path=args.history,
        calibration_out=args.calibration_out,
    )

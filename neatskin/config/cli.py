"""`neatskin protocol init DIR [--from paper|smoke|FILE]`: a protocol with its hardware files, as a template."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "protocol",
        help="start a protocol of your own from a packaged one",
        description="Start a protocol of your own from a packaged one (paper, smoke) or any protocol file.",
    )
    sub = parser.add_subparsers(dest="protocol_command", metavar="ACTION", required=True)
    init = sub.add_parser(
        "init",
        help="copy a protocol and the skin, wiring and printer files it names into a new folder, to edit",
        description="Copies regular files only (no links), keeping their paths relative to the protocol, so "
        "`neatskin campaign check DIR/<protocol>.toml` reads nothing outside DIR.",
    )
    init.add_argument("folder", type=Path, help="new folder for the template")
    init.add_argument(
        "--from", dest="source", default="paper", help="packaged protocol name (paper, smoke) or a protocol file"
    )
    init.set_defaults(handler=_init)


def _init(args: argparse.Namespace) -> int:
    from neatskin.config.template import init_protocol

    written = init_protocol(args.folder, args.source)
    for path in written:
        print(f"wrote {path}")
    print(f"edit them, then: neatskin campaign check {written[0]}")
    return 0

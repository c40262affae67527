"""The CLI's shared vocabulary: one spelling per concept for every component's options, and the shared groups.

Every component's `cli.py` adds its options through these, so `--out`, `--quiet` and
`--connect-timeout-s` mean one thing everywhere. An older spelling stays accepted as a hidden alias
(`HIDDEN_ALIASES`: it works, `--help` does not show it), so scripts and notes written for it keep
working. `command_group` finds a group that `neatskin.cli` declared (`campaign`, `printer`) for a
component to add its commands to.
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any, NoReturn

HIDDEN_ALIASES = frozenset({"--output", "--no-progress", "--connect-timeout", "--boot-timeout-s"})
"""Deprecated spellings: accepted, not shown in --help (docs/cli.md, "One spelling per concept")."""


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter without the hidden aliases in an option's list of spellings."""

    def _format_action_invocation(self, action: argparse.Action) -> str:
        shown = [s for s in action.option_strings if s not in HIDDEN_ALIASES]
        if shown == action.option_strings or not shown:
            return super()._format_action_invocation(action)
        visible = argparse.Action(shown, action.dest, nargs=action.nargs, metavar=action.metavar)
        return super()._format_action_invocation(visible)


class Parser(argparse.ArgumentParser):
    """The `neatskin` parser: its sub-parsers (of every level) share the formatter that hides the aliases, and
    a usage error names an option by its shown spellings only."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        for alias in HIDDEN_ALIASES:  # "argument --connect-timeout-s/--connect-timeout/...: " -> "--connect-timeout-s"
            message = re.sub(re.escape("/" + alias) + r"(?=[/:\s]|$)", "", message)
        super().error(message)


def add_out(parser: argparse.ArgumentParser, help: str, *, required: bool = False, default: Any = None) -> None:
    """-o/--out: where a command writes (a file or a folder, as its help says)."""
    parser.add_argument("-o", "--out", "--output", dest="out", type=Path, required=required, default=default, help=help)


def add_quiet(parser: argparse.ArgumentParser) -> None:
    """-q/--quiet: no progress bar."""
    parser.add_argument("-q", "--quiet", "--no-progress", dest="quiet", action="store_true", help="no progress bar")


def positive_finite(text: str) -> float:
    """argparse type of a timeout, deadline or limit: a finite number > 0. nan and inf would never be reached (a
    silent port waited on for ever), 0 and less would give up before starting: each is a usage error (exit 2)
    naming the option."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (give a finite number > 0, e.g. 5)") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number > 0 (give e.g. 5)")
    return value


def positive_count(text: str) -> int:
    """argparse type of a count of things to do (`--limit`): a whole number of 1 or more."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (give 1 or more)") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} is not 1 or more (leave the option out for no limit)")
    return value


def tcp_port(text: str) -> int:
    """argparse type of a TCP port to listen on: 0 (a free one) to 65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number (give 1024 to 65535, or 0)") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value} is not a TCP port (give 1024 to 65535, or 0 for a free one)")
    return value


# What --connect-timeout-s does not bound, said in its help: the handshake after the boot wait (the Marlin
# driver's DriverConfig defaults: M110 N0 sent 1 + probe_attempts times, min_timeout_s each; connect_timeout_s
# while the printer only says busy). tests/test_cli_vocabulary.py holds these figures to DriverConfig.
HANDSHAKE_TRIES, HANDSHAKE_TRY_S, HANDSHAKE_BUSY_MAX_S = 4, 2.0, 30.0
CONNECT_AFTER_BOOT = (
    f"; this bounds only the wait for `start`: the handshake after it (M110 N0) gives up on a silent or garbled "
    f"printer {HANDSHAKE_TRIES * HANDSHAKE_TRY_S:g} s later ({HANDSHAKE_TRIES} tries of {HANDSHAKE_TRY_S:g} s), "
    f"on one that only says busy {HANDSHAKE_BUSY_MAX_S:g} s later"
)


def add_connect_timeout(parser: argparse.ArgumentParser, default: float | None, help: str) -> None:
    """--connect-timeout-s: how long to wait for the printer's boot banner after opening its port; its help says
    what it does not bound (the handshake after it)."""
    parser.add_argument(
        "--connect-timeout-s",
        "--connect-timeout",
        "--boot-timeout-s",
        dest="connect_timeout_s",
        type=positive_finite,
        default=default,
        metavar="S",
        help=help + CONNECT_AFTER_BOOT,
    )


def command_group(subparsers: Any, name: str, help_text: str) -> Any:
    """The sub-command action of group `name`: the one `neatskin.cli` declared, or a new one (one owner)."""
    parser = subparsers.choices.get(name) if hasattr(subparsers, "choices") else None
    if parser is None:
        parser = subparsers.add_parser(name, help=help_text, description=help_text)
        return parser.add_subparsers(dest=f"{name}_command", metavar=f"{name.upper()}_COMMAND", required=True)
    for action in parser._actions:  # noqa: SLF001 - argparse keeps no public handle on it
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            return action
    return parser.add_subparsers(dest=f"{name}_command", metavar=f"{name.upper()}_COMMAND", required=True)

"""Sub-command groups shared by several components' CLIs (`neatskin sim ...`, `neatskin printer ...`)."""

from __future__ import annotations

import argparse


def command_group(subparsers, name: str, help_text: str):
    """The sub-command action of group `name`, created or (if another component made it) reused."""
    parser = subparsers.choices.get(name) if hasattr(subparsers, "choices") else None
    if parser is None:
        parser = subparsers.add_parser(name, help=help_text, description=help_text)
        return parser.add_subparsers(dest=f"{name}_command", metavar=f"{name.upper()}_COMMAND", required=True)
    for action in parser._actions:  # noqa: SLF001 - argparse keeps no public handle on it
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            return action
    return parser.add_subparsers(dest=f"{name}_command", required=True)

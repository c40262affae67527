"""The `neatskin` command: a thin argparse layer over functions a user can also call from Python.

Each component owns its subcommands in a `cli` module with a `register(subparsers)` function;
handlers import their heavy dependencies lazily so `neatskin --help` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from pathlib import Path

from neatskin.errors import NeatskinError

COMMAND_MODULES = (
    "neatskin.config.cli",
    "neatskin.skin.cli",
    "neatskin.gcode.cli",
    "neatskin.marlin.cli",
    "neatskin.sim.cli",
    "neatskin.acquisition.cli",
    "neatskin.rig.cli",
    "neatskin.datasets.cli",
    "neatskin.baselines.cli",
    "neatskin.monitor.cli",
    "neatskin.design.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="neatskin", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action=_VersionAction, help="show program's version number and exit")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue  # an optional component left out of this installation
        module.register(subparsers)
    return parser


class _VersionAction(argparse.Action):
    """argparse's "version" action, with the version looked up only when asked for."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None) -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        import neatskin

        print(f"neatskin-rig {neatskin.__version__}")  # to stdout, as argparse's own version action
        parser.exit()


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = format_warning  # one line each, in the toolkit's voice (not file:line: Class: ...)
    try:
        result = args.handler(args)
    except NeatskinError as exc:
        print(f"neatskin: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"neatskin: interrupted{': ' + str(exc) if str(exc) else ''}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _quiet_broken_pipe()
    try:
        sys.stdout.flush()  # a reader that left (`| head`) shows here, not as a traceback at exit
    except BrokenPipeError:
        return _quiet_broken_pipe()
    return int(result or 0)


def format_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as one line: `neatskin: warning: <text>`, the text's own line breaks folded. A warning from
    a library (numpy, scikit-learn) names its kind and module so it can be looked up; no source line is shown."""
    text = " ".join(str(message).split())
    module = getattr(category, "__module__", "")
    if module.startswith("neatskin") or category is UserWarning:
        return f"neatskin: warning: {text}\n"
    origin = Path(filename).stem if filename else "?"
    return f"neatskin: warning ({category.__name__} in {origin}): {text}\n"


def _quiet_broken_pipe() -> int:
    """The reader of our output went away (e.g. `neatskin dataset info X | head`): stop quietly, as Unix tools
    do. stdout is pointed at /dev/null so the interpreter's own final flush does not fail again."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 141  # 128 + SIGPIPE, what a shell reports for a tool killed by a closed pipe


if __name__ == "__main__":
    sys.exit(main())

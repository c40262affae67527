"""The `neatskin` command: a thin argparse layer over functions a user can also call from Python.

Composition, in this one place: each component owns its commands in a `cli` module with a
`register(subparsers)` function; the groups that several components add commands to (`campaign`,
`printer`) are declared here, before any component registers, so no group depends on the order of
`COMMAND_MODULES`. Options come from one vocabulary (`neatskin.cligroups`); every error ends here,
printed in one format with the exit code of its kind (`neatskin.errors.ExitCode`, docs/cli.md).
Handlers import their heavy dependencies lazily so `neatskin --help` stays fast.

argparse, not click: the 10 components already register through argparse, their tests call
`main([...])` with argument lists, and the vocabulary, the hidden aliases and the exit-code table are
small on top of it; click would rewrite every `cli.py` (and the tests' calls) for the same behaviour.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from pathlib import Path

from neatskin.cligroups import Parser, command_group
from neatskin.errors import DataError, ExitCode, NeatskinError, exit_code_of
from neatskin.oserrors import os_error

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


DESCRIPTION = (
    "Press campaigns on a NeatSkin sensor: run one from a protocol on the real rig or with --dry-run (a simulated "
    "printer and skin), then curate the dataset and fit the position baselines. `neatskin COMMAND --help` for each."
)
# The groups several components add commands to, each declared once: (name, help).
SHARED_GROUPS = (
    ("campaign", "run, resume, finish, check or plan a press campaign; pause, continue or stop a running one"),
    ("printer", "talk to a Marlin printer over its serial port"),
)


def build_parser() -> argparse.ArgumentParser:
    codes = ", ".join(f"{int(code)} {code.name.lower().replace('_', ' ')}" for code in ExitCode)
    parser = Parser(prog="neatskin", description=DESCRIPTION, epilog=f"exit codes: {codes} (docs/cli.md)")
    parser.add_argument("--version", action=_VersionAction, help="show program's version number and exit")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, help_text in SHARED_GROUPS:
        command_group(subparsers, name, help_text)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue  # an optional component left out of this installation
        module.register(subparsers)
    _describe_commands(parser)
    return parser


def _describe_commands(parser: argparse.ArgumentParser) -> None:
    """Every command's own --help says what it does: one registered without a description gets its help line (the
    line its group's --help lists), so `neatskin dataset split --help` is never usage and arguments alone."""
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        said = {choice.dest: choice.help for choice in action._choices_actions}
        for name, sub in action.choices.items():
            if sub.description is None and said.get(name):
                help_text = str(said[name]).replace("%%", "%")  # a help line's escape; a description is not formatted
                sub.description = help_text[0].upper() + help_text[1:] + ("" if help_text.endswith(".") else ".")
            _describe_commands(sub)


class _VersionAction(argparse.Action):
    """argparse's "version" action, with the version looked up only when asked for."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None) -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        import neatskin

        print(f"neatskin-rig {neatskin.__version__}")  # to stdout, as argparse's own version action
        parser.exit()


def main(argv: list[str] | None = None) -> int:
    try:  # building the parser imports every command's module (~0.4 s): a Ctrl-C then is an interrupt too
        parser = build_parser()
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        print("neatskin: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
    warnings.formatwarning = format_warning  # one line each, in the toolkit's voice (not file:line: Class: ...)
    try:
        result = args.handler(args)
    except NeatskinError as exc:
        report_error(exc)
        return exit_code_of(exc)
    except KeyboardInterrupt as exc:
        print(f"neatskin: interrupted{': ' + str(exc) if str(exc) else ''}", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except BrokenPipeError:
        return _quiet_broken_pipe()
    except OSError as exc:  # a path no check of the command named (an output folder it cannot write, ...)
        error = path_error(exc)
        report_error(error)
        return exit_code_of(error)
    try:
        sys.stdout.flush()  # a reader that left (`| head`) shows here, not as a traceback at exit
    except BrokenPipeError:
        return _quiet_broken_pipe()
    return int(result or 0)


def path_error(exc: OSError) -> DataError:
    """One DataError for an OSError that reached the CLI: the path, the system's reason, a fix for it."""
    return os_error(exc, "use")


def report_error(exc: NeatskinError) -> None:
    """The one error format: `neatskin: error: file: [field]: what (fix: how)`, one line per problem."""
    problems = getattr(exc, "problems", None)
    lines = [p.text(cli=True) for p in problems] if problems else str(exc).splitlines() or [type(exc).__name__]
    for line in lines:
        print(f"neatskin: error: {line}", file=sys.stderr)


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
    return ExitCode.BROKEN_PIPE  # 128 + SIGPIPE, what a shell reports for a tool killed by a closed pipe


if __name__ == "__main__":
    sys.exit(main())

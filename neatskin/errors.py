"""The toolkit's error types: one per kind of failure, each naming what was wrong and the fix.

- ConfigError: a protocol, layout, wiring or printer-profile file (or the values built
  from it) is wrong. Raised before any motion.
- HardwareError: the printer, the serial line or the DAQ failed or is missing.
- DataError: a dataset (parquet, manifest) is malformed or inconsistent.
- CheckFailed: a check command (`campaign check`, `gcode check`, `dataset validate`) found problems
  in what it was asked to check.

`ExitCode` is the one table of the `neatskin` command's exit codes: each kind its own code, so a
script (or an operator) tells a dead printer from a typo.

ConfigError and DataError carry one or more Problems (file, field, message, fix) so that a
validator can report every mistake in a file at once.

confirm_cost(estimate_s, limit_s, yes, what=..., basis=..., flag="--yes") is the one refusal of heavy work: a
command that can run for hours prints its estimate with it first, and is refused beyond its limit unless told.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum
from os import PathLike


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an input: where (file, field), what, and how to fix it."""

    message: str
    file: str | None = None
    field: str | None = None
    fix: str | None = None
    cli_fix: str | None = None  # the fix as a `neatskin` command line, where `fix` names a Python keyword

    def __str__(self) -> str:
        return self.text(cli=False)

    def text(self, *, cli: bool) -> str:
        """`file: [field]: message (fix: ...)`; cli: the fix in the command line's words when it has them (the CLI's
        error lines; str() gives the Python caller's)."""
        where = ": ".join(part for part in (self.file, f"[{self.field}]" if self.field else None) if part)
        text = f"{where}: {self.message}" if where else self.message
        fix = self.cli_fix if cli and self.cli_fix else self.fix
        return f"{text} (fix: {fix})" if fix else text


class NeatskinError(Exception):
    """Base of every error this toolkit raises on purpose."""


class _ProblemError(NeatskinError):
    def __init__(
        self,
        message: str | None = None,
        *,
        file: str | PathLike | None = None,
        field: str | None = None,
        fix: str | None = None,
        problems: Iterable[Problem] | None = None,
        cli_fix: str | None = None,
    ) -> None:
        if problems is None:
            if message is None:
                raise TypeError("give a message or a list of problems")
            problems = [Problem(message, None if file is None else str(file), field, fix, cli_fix)]
        self.problems: tuple[Problem, ...] = tuple(problems)
        if not self.problems:
            raise TypeError("an error needs at least one problem")
        super().__init__("\n".join(str(p) for p in self.problems))

    @property
    def file(self) -> str | None:
        return self.problems[0].file

    @property
    def field(self) -> str | None:
        return self.problems[0].field


class ConfigError(_ProblemError):
    """A protocol, layout, wiring or printer-profile file is wrong; nothing has moved."""


class DataError(_ProblemError):
    """A dataset is malformed or inconsistent."""


class HardwareError(NeatskinError):
    """The printer, the serial line or the DAQ failed, or is missing."""


class CheckFailed(_ProblemError):
    """A check command ran and found problems in what it was asked to check (its verdict, not a failure to run)."""


class ExitCode(IntEnum):
    """The exit codes of the `neatskin` command (docs/cli.md lists them)."""

    OK = 0
    CHECK_FAILED = 1  # campaign check, gcode check, dataset validate: the input fails the check
    USAGE = 2  # argparse: an unknown option, a missing argument
    CONFIG = 3  # ConfigError: a protocol, layout, wiring or profile file (or an option's value) is wrong
    HARDWARE = 4  # HardwareError: the printer, the serial line or the DAQ failed or is missing
    DATA = 5  # DataError: a dataset or campaign folder is malformed, or cannot be written
    INTERRUPTED = 130  # Ctrl-C, SIGTERM, SIGHUP or `campaign stop` (128 + SIGINT); a campaign stays resumable
    BROKEN_PIPE = 141  # the reader of the output went away (`| head`; 128 + SIGPIPE)


def exit_code_of(error: BaseException) -> ExitCode:
    """The exit code of an error the command ends with."""
    for kind, code in (
        (CheckFailed, ExitCode.CHECK_FAILED),
        (ConfigError, ExitCode.CONFIG),
        (HardwareError, ExitCode.HARDWARE),
        (DataError, ExitCode.DATA),
        (KeyboardInterrupt, ExitCode.INTERRUPTED),
        (BrokenPipeError, ExitCode.BROKEN_PIPE),
    ):
        if isinstance(error, kind):
            return code
    return ExitCode.CONFIG  # a NeatskinError of no kind: raised on purpose about the input


def raise_problems(problems: list[Problem], kind: type[_ProblemError] = ConfigError) -> None:
    """Raise one error listing every problem, if there are any."""
    if problems:
        raise kind(problems=problems)


def format_duration(seconds: float) -> str:
    """A duration as a technician reads it: '40 s', '12 min', '3.2 h', '4.1 days'."""
    if not seconds < float("inf"):
        return "for ever"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    if seconds < 172_800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86_400:.1f} days"


def confirm_cost(
    estimate_s: float,
    limit_s: float,
    yes: bool,
    *,
    what: str,
    basis: str = "",
    flag: str = "--yes",
    load_scaled: bool = False,
    out=None,
) -> None:
    """Print the estimated time of heavy work before it starts; refuse (ConfigError naming `flag`) beyond
    `limit_s` unless `yes`. Every command that can run for hours calls it before its first heavy step.

    estimate_s: the estimated wall time; limit_s: the most a command runs without being told to go on;
    what: the work ('design study grid5: 7 candidates'); basis: how the estimate was made (shown with it);
    load_scaled: the estimate already allows for the machine's load (else a busy machine is noted beside it)."""
    import sys

    stream = sys.stderr if out is None else out
    note = f" ({basis})" if basis else ""
    busy = "" if load_scaled else _busy_note()
    note += f"; {busy}" if busy else ""
    print(f"{what}: estimated {format_duration(estimate_s)}{note}", file=stream)
    if estimate_s > limit_s and not yes:
        raise ConfigError(
            f"{what} would take about {format_duration(estimate_s)}, more than the {format_duration(limit_s)} "
            "a command runs without being asked",
            field=flag,
            fix=f"pass {flag} to run it anyway, or make it smaller",
        )


def _busy_note() -> str:
    """Said beside an estimate when other work already holds the cores (the estimate assumes them free)."""
    import os

    try:
        load, cores = os.getloadavg()[0], len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return ""
    return f"the machine is busy (load {load:.1f} on {cores} cores): expect longer" if load > cores else ""

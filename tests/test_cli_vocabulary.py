"""One CLI vocabulary: every argument and sub-command has help, one spelling per concept, one exit-code table
(checked through the real command in a subprocess), one error format."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from neatskin.cli import build_parser
from neatskin.cligroups import HIDDEN_ALIASES
from neatskin.errors import ExitCode

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = ROOT / "protocols"


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, action, parser) for every argument of every (sub-)command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helped = {choice.dest: choice.help for choice in action._choices_actions}
            seen: set[int] = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias (`dataset describe` of `info`): its help is its command's
                    continue
                seen.add(id(sub))
                yield (*path, name), helped.get(name), None
                yield from _walk(sub, (*path, name))
        else:
            yield path, action.help, action


def test_every_argument_and_sub_command_has_help():
    missing = []
    for path, help_text, action in _walk(build_parser()):
        name = (
            " ".join(path) if action is None else f"{' '.join(path)} {'/'.join(action.option_strings) or action.dest}"
        )
        if action is not None and action.help == argparse.SUPPRESS:
            continue
        if not help_text:
            missing.append(name)
    assert missing == []


def test_one_spelling_per_concept():
    spellings: dict[str, set[str]] = {}
    for _path, _, action in _walk(build_parser()):
        if action is None:
            continue
        for option in action.option_strings:
            spellings.setdefault(action.dest, set()).add(option)
    assert {"--out", "-o"} <= spellings["out"] and "output" not in spellings
    assert {"--quiet", "-q"} <= spellings["quiet"] and "no_progress" not in spellings
    assert "--connect-timeout-s" in spellings["connect_timeout_s"]
    assert "connect_timeout" not in spellings and "boot_timeout_s" not in spellings


def test_help_hides_the_old_spellings_and_they_still_work():
    parser = build_parser()
    text = parser.parse_args  # the parser is built once for both checks
    sub = parser._subparsers._group_actions[0].choices["printer"]._subparsers._group_actions[0].choices["send"]
    shown = sub.format_help()
    assert "--connect-timeout-s" in shown and "--quiet" in shown
    assert not any(alias in shown.split() for alias in HIDDEN_ALIASES)
    args = text(["printer", "send", "f.gcode", "--port", "/dev/null", "--boot-timeout-s", "0.5", "--no-progress"])
    assert args.connect_timeout_s == 0.5 and args.quiet is True


def _neatskin(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "neatskin", *argv], capture_output=True, text=True, timeout=120, env=env, cwd=cwd
    )


def test_exit_codes_through_the_real_command(tmp_path):
    usage = _neatskin("campaign", "run")  # the protocol is missing
    assert usage.returncode == ExitCode.USAGE == 2, usage.stderr

    bad = tmp_path / "bad.toml"
    bad.write_text((PROTOCOLS / "smoke.toml").read_text().replace("[campaign]", "[campain]"))
    config = _neatskin("gcode", "generate", str(bad), "-o", str(tmp_path / "x.gcode"))
    assert config.returncode == ExitCode.CONFIG == 3, config.stderr
    assert config.stderr.startswith(f"neatskin: error: {bad}: [campain]: unknown table [campain]")

    program = tmp_path / "ok.gcode"
    program.write_text("G28\n")
    hardware = _neatskin("printer", "send", str(program), "--port", str(tmp_path / "no-such-port"), "-q")
    assert hardware.returncode == ExitCode.HARDWARE == 4, hardware.stderr
    assert hardware.stderr.startswith("neatskin: error: ") and "Traceback" not in hardware.stderr

    data = _neatskin("dataset", "info", str(tmp_path / "no-such-dataset"))
    assert data.returncode == ExitCode.DATA == 5, data.stderr
    assert data.stderr.startswith("neatskin: error: ") and "Traceback" not in data.stderr


def test_a_failed_check_exits_1_in_every_check_command(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((PROTOCOLS / "smoke.toml").read_text().replace("[campaign]", "[campain]"))
    campaign = _neatskin("campaign", "check", str(bad))
    gcode_file = tmp_path / "bad.gcode"
    gcode_file.write_text("G28\nM500\n")  # M500 writes the EEPROM: not a press-program command
    gcode = _neatskin("gcode", "check", str(gcode_file))
    assert campaign.returncode == gcode.returncode == ExitCode.CHECK_FAILED == 1, (campaign.stderr, gcode.stderr)
    for done in (campaign, gcode):
        assert done.stderr and all(line.startswith("neatskin: error: ") for line in done.stderr.splitlines())


@pytest.mark.parametrize("code", list(ExitCode))
def test_the_docs_and_the_help_list_every_exit_code(code):
    table = (ROOT / "docs" / "cli.md").read_text()
    assert f"| {int(code)} | `{code.name}` |" in table
    assert f"{int(code)} {code.name.lower().replace('_', ' ')}" in " ".join(build_parser().format_help().split())


def _is_a_time_limit(action: argparse.Action) -> bool:
    """An option whose value is a timeout, a deadline, a time limit (seconds or hours) or a time scale (the sim
    printer's --speed: nan stalled its clock)."""
    dest = action.dest or ""
    return (
        any(word in dest for word in ("timeout", "deadline")) or dest.endswith(("_hours", "max_s")) or dest == "speed"
    )


def test_every_time_limit_option_takes_only_a_finite_number_above_zero():
    """nan or inf would never be reached (a silent port waited on for ever), 0 or less gives up at once."""
    from neatskin.cligroups import positive_finite

    limits = [(path, action) for path, _, action in _walk(build_parser()) if action and _is_a_time_limit(action)]
    assert {"connect_timeout_s", "max_hours", "speed"} <= {action.dest for _, action in limits}
    assert all(action.type is positive_finite for _, action in limits), [
        (path, action.dest) for path, action in limits if action.type is not positive_finite
    ]


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-5", "5s"])
def test_a_connect_timeout_that_never_ends_or_never_starts_is_a_usage_error_before_the_port(tmp_path, value):
    """A silent port (a pty whose master is open and never answers): refused at once, exit 2, naming the option
    by its shown spelling, nothing written to the port and no campaign folder made."""
    import pty

    master, slave = pty.openpty()
    port = os.ttyname(slave)
    program = tmp_path / "p.gcode"
    program.write_text("G28\n")
    try:
        send = _neatskin("printer", "send", str(program), "--port", port, "--connect-timeout-s", value, "-q")
        run = _neatskin(
            "campaign", "run", str(PROTOCOLS / "smoke.toml"), "--port", port, "--daq", "simulated", "-o",
            str(tmp_path / "run"), "--no-report", "-q", "--connect-timeout", value,
        )  # fmt: skip
        for done in (send, run):
            assert done.returncode == ExitCode.USAGE, done.stderr
            assert done.stderr.splitlines()[-1].endswith(
                f"error: argument --connect-timeout-s: {value!r} is not a number (give a finite number > 0, e.g. 5)"
                if value == "5s"
                else f"error: argument --connect-timeout-s: {value} is not a finite number > 0 (give e.g. 5)"
            ), done.stderr
        os.set_blocking(master, False)
        with pytest.raises(BlockingIOError):
            os.read(master, 1024)  # not a byte reached the printer's port
        assert not (tmp_path / "run").exists()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--limit", "-3", "argument --limit: -3 is not 1 or more (leave the option out for no limit)"),
        ("--limit", "0", "argument --limit: 0 is not 1 or more (leave the option out for no limit)"),
        ("--monitor-port", "99999", "argument --monitor-port: 99999 is not a TCP port (give 1024 to 65535, or 0"),
        ("--monitor-port", "-1", "argument --monitor-port: -1 is not a TCP port (give 1024 to 65535, or 0"),
    ],
)
def test_a_count_or_port_out_of_range_is_a_usage_error_before_anything_starts(tmp_path, option, value, message):
    """Before: --limit -3 pressed 9 of 12 (todo[:-3]); --monitor-port 99999 printed the monitor's traceback and
    the campaign went on. Now exit 2 naming the option; no campaign folder."""
    done = _neatskin(
        "campaign", "run", str(PROTOCOLS / "smoke.toml"), "--dry-run", "-o", str(tmp_path / "run"), "-q",
        "--no-report", "--monitor", f"{option}={value}",
    )  # fmt: skip
    assert done.returncode == ExitCode.USAGE, done.stderr
    assert message in done.stderr.splitlines()[-1] and "Traceback" not in done.stderr
    assert not (tmp_path / "run").exists()
    monitor = _neatskin("monitor", str(tmp_path), "--port", "70000")
    assert monitor.returncode == ExitCode.USAGE and "argument --port: 70000 is not a TCP port" in monitor.stderr


def test_a_monitor_port_in_use_names_monitor_port_before_anything_starts(tmp_path):
    """On `campaign run` --port is the printer's serial port: the live page's port in use names --monitor-port,
    exit 3, before the campaign folder exists."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = _neatskin(
            "campaign", "run", str(PROTOCOLS / "smoke.toml"), "--dry-run", "-o", str(tmp_path / "run"), "-q",
            "--no-report", "--monitor", "--monitor-port", str(port),
        )  # fmt: skip
    assert done.returncode == ExitCode.CONFIG, done.stderr
    assert done.stderr.splitlines() == [
        f"neatskin: error: [--monitor-port]: the live page cannot listen on 127.0.0.1:{port}: Address already in use "
        "(fix: choose another port (--monitor-port 0 picks a free one), or stop the other monitor)"
    ]
    assert not (tmp_path / "run").exists()

"""A Ctrl-C while the CLI still imports its commands' modules (the first ~0.4 s of any command) is an interrupt
like any other: one line and exit 130, not a traceback (found by sending SIGINT 0.3 s after the start)."""

import importlib

from neatskin import cli
from neatskin.errors import ExitCode


def test_ctrl_c_while_the_commands_load_is_one_line_and_exit_130(monkeypatch, capsys):
    real = importlib.import_module

    def import_module(name, *args):
        if name.startswith("neatskin.") and name.endswith(".cli"):  # a command group's module: where it landed
            raise KeyboardInterrupt
        return real(name, *args)

    monkeypatch.setattr(cli.importlib, "import_module", import_module)
    assert cli.main(["campaign", "run", "protocols/smoke.toml", "--dry-run"]) == ExitCode.INTERRUPTED == 130
    assert capsys.readouterr().err == "neatskin: interrupted\n"

"""What `neatskin ... --help` prints reads as written: argparse %-formats an argument's help but not a command's
description, so a '%%' written there to escape a per cent sign is printed as '%%' (`neatskin skin maps --help`
said "each channel +50 %% in turn")."""

import argparse

from neatskin.cli import build_parser


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("neatskin",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_no_help_page_prints_a_doubled_per_cent_sign():
    pages = {" ".join(path): parser.format_help() for path, parser in _parsers(build_parser())}
    assert len(pages) >= 40  # every command and sub-command (40 today), not just the top
    assert [name for name, text in pages.items() if "%%" in text] == []
    assert "each channel +50 % in turn" in " ".join(pages["neatskin skin maps"].split())

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


def _pages():
    return {" ".join(path): (parser, parser.format_help()) for path, parser in _parsers(build_parser())}


def _summaries(parser: argparse.ArgumentParser) -> dict[str, str]:
    """{command: its one-line help} of a parser's sub-commands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {choice.dest: " ".join((choice.help or "").split()) for choice in action._choices_actions}
    return {}


def test_every_group_says_what_it_is_and_no_description_stops_mid_sentence():
    """`neatskin dataset --help` ended "a thin layer over neatskin.datasets.curate," (the first line of a docstring);
    `protocol` and `mux` had no description at all."""
    pages = _pages()
    for name, (parser, _) in pages.items():
        if _summaries(parser):  # a group: its page says what it is
            assert parser.description, name
        text = " ".join((parser.description or "").split())
        assert not text.endswith((",", ";", ":", "-", " and", " or", " the")), (name, text)
    top = " ".join(pages["neatskin"][1].split())
    assert "thin argparse layer" not in top and "--dry-run" in top  # for a user, not the module's reader


def test_a_groups_summary_names_only_commands_that_exist_and_every_action_of_it():
    """The top-level help said "validate, describe, ..." for `dataset`, whose command is `info` (`dataset describe`
    failed), `skin` said only "sensitivity maps" beside press, fit and mechanics, `campaign` left out plan."""
    parser = build_parser()
    top = _summaries(parser)
    groups = {name: sub for name, (sub, _) in _pages().items() if name.count(" ") == 1}
    for group in ("campaign", "dataset"):  # the summaries that list their commands: every one, and only those
        commands = set(_summaries(groups[f"neatskin {group}"]))
        listed = {w.strip(",;()") for w in top[group].replace(" or ", ", ").replace(" and ", ", ").split()}
        assert commands <= listed, (group, commands - listed)
    assert top["dataset"].startswith("describe (info), validate, merge, split, export and plot")
    assert (
        parser.parse_args(["dataset", "describe", "x"]).handler is parser.parse_args(["dataset", "info", "x"]).handler
    )
    for words in ("sensitivity maps", "one press's R_eq", "fit to a campaign", "finite-element pinch"):
        assert words in top["skin"]  # maps, press, fit, mechanics


def test_no_option_help_breaks_a_name_across_lines():
    """argparse wraps at spaces only: `--models` listed "ridge,knn,kernel_ridge,extra_trees,mlp,..." without one and
    printed "ml" and "p" on two lines."""
    from neatskin.baselines.models import MODEL_NAMES

    page = " ".join(_pages()["neatskin baselines"][1].split())
    assert all(f" {name}," in page or f" {name})" in page for name in (*MODEL_NAMES, "inversion")), page

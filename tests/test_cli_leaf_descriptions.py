"""Every command's own --help says what it does (a newcomer audit found 16, `dataset split` and `campaign plan`
among them, that printed usage and arguments alone): a description, the group's help line where none was given."""

import argparse

import pytest

from neatskin.cli import build_parser, main


def _leaves(parser, path=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            said = {choice.dest: choice.help for choice in action._choices_actions}
            for name, sub in action.choices.items():
                if any(isinstance(a, argparse._SubParsersAction) for a in sub._actions):
                    yield from _leaves(sub, (*path, name))
                else:
                    yield (*path, name), sub, said.get(name)


LEAVES = list(_leaves(build_parser()))


def test_there_are_leaf_commands_to_check():
    names = {" ".join(path) for path, _, _ in LEAVES}
    assert {"dataset split", "campaign plan", "campaign check", "gcode generate", "mux table"} <= names


@pytest.mark.parametrize(("path", "sub", "help_line"), LEAVES, ids=[" ".join(p) for p, _, _ in LEAVES])
def test_every_command_help_says_what_it_does(path, sub, help_line):
    if sub.description is not None and help_line and sub.description.rstrip(".").lower() == help_line.lower():
        assert sub.description[0].isupper()  # a generated one: the group's line, as a sentence
    text = " ".join((sub.description or "").split())
    assert len(text) > 15 and text[0].isupper() and text.endswith("."), (path, text)
    assert "%%" not in text


def test_the_description_is_printed(capsys):
    with pytest.raises(SystemExit):
        main(["dataset", "split", "--help"])
    out = capsys.readouterr().out
    assert "Split into train/ and test/ by position (repeats never straddle)." in out

"""`neatskin skin press` refuses a press the skin cannot take, as a protocol does, instead of printing plausible
numbers (an audit pressed at x = 500 mm, at -1 mm and 30 mm deep into a 5.5 mm skin: all exit 0 before)."""

import pytest

from neatskin import cli
from neatskin.errors import ExitCode


@pytest.mark.parametrize(
    ("where", "message"),
    [
        (["--x-mm", "500", "--y-mm", "0"], "a probe of radius 2.75 mm at (500, 0) mm misses the skin's channels"),
        (["--x-mm", "-2.76", "--y-mm", "15"], "misses the skin's channels (x 0 to 30, y 0 to 30 mm)"),
        (["--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "-1"], "--depth-mm -1 is above the surface"),
        (["--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "30"], "--depth-mm 30 is through the skin"),
        (["--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "5.5"], "is 5.5 mm thick"),
    ],
)
def test_a_press_off_the_skin_or_through_it_is_one_error(capsys, where, message):
    assert cli.main(["skin", "press", *where]) == ExitCode.CONFIG
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    "where",
    [
        ["--x-mm", "-2.7", "--y-mm", "15"],  # the footprint's edge still on the edge channel
        ["--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "0"],  # no press: the baseline
        ["--x-mm", "7.5", "--y-mm", "0", "--depth-mm", "5.4"],
    ],
)
def test_a_press_the_skin_can_take_is_answered(capsys, where):
    assert cli.main(["skin", "press", *where]) == 0
    out = capsys.readouterr().out
    assert out.startswith("press at (") and out.count("\n") == 2 + 28

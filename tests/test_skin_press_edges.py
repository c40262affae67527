"""`skin press` / `skin netlist` at their edges: --pinch ratios past the floats' range, and a kernel still to solve."""

from __future__ import annotations

import pytest

from neatskin import cli
from neatskin.errors import ConfigError, ExitCode
from neatskin.layout import load_layout
from neatskin.skin.clipress import DEFAULT_LAYOUT, parse_pinches


@pytest.mark.parametrize(
    ("ratio", "says"),
    [
        ("1e400", "overflows"),  # float() makes it inf: a shut channel nobody asked for
        ("1e-400", "underflows to 0"),  # float() makes it 0: "must be > 0" of a positive number
        ("0", "must be a number > 0"),
        ("-1", "must be a number > 0"),
        ("nan", "must be a number > 0"),
        ("abc", "must be a number > 0"),
    ],
)
def test_a_pinch_ratio_the_floats_cannot_hold_is_refused_saying_why(ratio, says):
    layout = load_layout(DEFAULT_LAYOUT)
    with pytest.raises(ConfigError, match=says):
        parse_pinches(layout, [f"J00-J10={ratio}"])


def test_inf_shuts_and_a_tiny_or_huge_finite_ratio_is_kept_exactly():
    layout = load_layout(DEFAULT_LAYOUT)
    assert parse_pinches(layout, ["J00-J10=inf", "J00-J01=1e-300", "J01-J02=1e300"]) == {
        0: float("inf"),
        layout.channels.index(next(c for c in layout.channels if c.name == "J00-J01")): 1e-300,
        layout.channels.index(next(c for c in layout.channels if c.name == "J01-J02")): 1e300,
    }


def test_a_kernel_still_to_solve_is_announced_on_stderr_before_the_solve(monkeypatch, capsys):
    """With no kernel packaged or cached for the probe, the FE pinch takes minutes of CPU: the command says so
    first, on stderr (stdout may be the netlist), and then solves it (stood in here by the packaged kernel)."""
    import neatskin.skin.kernel as kernel_module

    real = kernel_module.load_kernel
    packaged = real(kernel_module.KernelSpec.for_layout(load_layout(DEFAULT_LAYOUT), 2.75))
    calls = []

    def load(spec, compute=True, n_jobs=2):
        calls.append(compute)
        if not compute:
            raise FileNotFoundError("no kernel")
        assert capsys.readouterr().err.count("first solving the finite-element pinch kernel") == 1
        return packaged

    monkeypatch.setattr(kernel_module, "load_kernel", load)
    assert cli.main(["skin", "netlist", "--x-mm", "7.5", "--y-mm", "0", "--deformation", "fe-kernel"]) == 0
    assert calls == [False, True]
    out = capsys.readouterr().out
    assert "first solving" not in out and ".end" in out  # the netlist on stdout is untouched
    assert cli.main(["skin", "press", "--x-mm", "7.5", "--y-mm", "0", "--deformation", "fe-kernel"]) == 0
    assert calls == [False, True, False, True]
    monkeypatch.setattr(kernel_module, "load_kernel", real)  # packaged: found at once, nothing said
    assert cli.main(["skin", "press", "--x-mm", "7.5", "--y-mm", "0", "--deformation", "fe-kernel"]) == 0
    assert "first solving" not in capsys.readouterr().err


def test_a_netlist_that_cannot_be_written_is_one_error_naming_its_path(capsys):
    """/dev/full accepts the open and fails the write with ENOSPC, an exception that names no file."""
    assert cli.main(["skin", "netlist", "-o", "/dev/full"]) == ExitCode.DATA
    err = capsys.readouterr().err
    assert "/dev/full" in err and "No space left on device" in err and "Traceback" not in err

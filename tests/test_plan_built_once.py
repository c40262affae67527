"""A dry run builds its plan once: the pressed-rails warning draws the presses from the plan the runner then presses
(before, the warning built its own: ~0.07 s of CPU for the paper protocol). `campaign run --dry-run` and
`campaign resume` of a dry campaign each call build_plan once, still print the warning (the resume's counting the
presses left), and press every press once."""

import re
import sys

import pyarrow.parquet as pq
import pytest
from test_resume_rails_warning import _left_line, _small_at

import neatskin.rig.cli
import neatskin.rig.railcheck
import neatskin.rig.runner
import neatskin.rig.simcampaign
from neatskin.cli import main
from neatskin.rig import plan as plan_module
from neatskin.rig.protocol import load_protocol


@pytest.fixture
def plans_built(monkeypatch):
    """The protocols build_plan is called with, wherever it is called from (every module that holds it)."""
    original = plan_module.build_plan
    calls = []

    def spy(protocol, *args, **kwargs):
        calls.append(protocol.name)
        return original(protocol, *args, **kwargs)

    for name, module in list(sys.modules.items()):
        if name.startswith("neatskin") and getattr(module, "build_plan", None) is original:
            monkeypatch.setattr(module, "build_plan", spy)
    assert plan_module.build_plan is spy and neatskin.rig.runner.build_plan is spy
    return calls


@pytest.mark.timeout(300)
def test_a_dry_run_and_its_resume_each_build_the_plan_once(tmp_path, plans_built, capsys):
    path = _small_at(tmp_path, "0.0005")
    check_line = neatskin.rig.railcheck.pressed_rails_text(load_protocol(path))
    plans_built.clear()
    run = tmp_path / "run"
    assert main(["campaign", "run", str(path), "--dry-run", "--limit", "3", "--no-report", "-q", "-o", str(run)]) == 0
    err = capsys.readouterr().err
    assert plans_built == ["paper"]
    assert [line for line in err.splitlines() if "past the rails" in line] == [f"{path}: {check_line}"]
    plans_built.clear()
    assert main(["campaign", "resume", str(run), "--no-report", "-q"]) == 0
    err = capsys.readouterr().err
    assert plans_built == ["paper"]
    rails = [line for line in err.splitlines() if "past the rails" in line]  # the presses left: press 18 of 37
    prefix = f"{run / 'inputs' / 'protocol.toml'}: "
    assert len(rails) == 1 and rails[0].startswith(prefix)
    assert re.fullmatch(_left_line(check_line, "0.5", 1, 37), rails[0][len(prefix) :])
    ids = pq.read_table(run / "presses.parquet", columns=["press_id"]).column("press_id").to_pylist()
    assert sorted(ids) == list(range(40))

"""`skin fit` on a dry run says when the campaign's skin is one its parametric pinch cannot describe: a dry run of the
paper-like scene presses the finite-element pinch kernel (docs/skin.md, "Fitting a skin to a recorded campaign").
Small real dry runs of the smoke protocol (16 positions x 2 presses: the kernel cuts pairs off, and the fit needs
4 positions left), their scene changed in the protocol's text, so the manifest records it as a user's protocol
would."""

import shutil

import pytest
from conftest import PROTOCOLS

from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.skin.fit import model_mismatch_warning

WARNING = "warning: this campaign's simulated skin pressed the finite-element pinch kernel"


def _dry_run(root, scene_lines: str):
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text().replace('signal = "waveforms"', 'signal = "features"')
    text = text.replace("waveforms = true", "waveforms = false").replace("count = 6", "count = 16")
    text = text.replace('preset = "ideal"', scene_lines)
    (root / "p.toml").write_text(text)
    folder = root / "campaign"
    run_campaign(load_protocol(root / "p.toml"), folder, dry_run=True, progress=False, report=False)
    return folder


@pytest.mark.parametrize(
    ("scene_lines", "warned", "exit_code"),
    [
        ('preset = "ideal"', False, 0),  # the parametric pinch: the fit's own model
        ('preset = "paper-like"', True, 0),  # deformation "auto": the preset's fe-kernel
        ('preset = "paper-like"\ndeformation = "parametric"', False, 0),  # the negative control: same scene
        # no placement error on the kernel: the shut channels leave the pinch unidentified, and the command refuses
        # (DataError, exit 5), the warning already out, saying why the model was the wrong one
        ('preset = "ideal"\ndeformation = "fe-kernel"', True, 5),
    ],
)
def test_the_fit_warns_once_first_exactly_when_the_dry_run_pressed_the_fe_kernel(
    tmp_path, capsys, scene_lines, warned, exit_code
):
    from neatskin.cli import main

    folder = _dry_run(tmp_path, scene_lines)
    profile = tmp_path / "fitted.toml"
    assert main(["skin", "fit", str(folder), "--out", str(profile)]) == exit_code
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert sum(WARNING in line for line in lines) == (1 if warned else 0)
    if warned:  # first, before the figures it qualifies
        assert lines[0].startswith(WARNING)
    if exit_code == 0:
        assert (WARNING.replace("warning: ", "# warning: ") in profile.read_text()) is warned
    else:
        assert "cannot identify pinch_gain" in captured.err and not profile.exists()


def test_a_real_skin_or_a_manifest_without_a_scene_gets_no_warning():
    fe_scene = {"protocol_as_run": {"scene": {"preset": "paper-like", "deformation": "fe-kernel"}}}
    assert model_mismatch_warning({**fe_scene, "rig": {"kind": "dry-run", "daq": "simulated"}}) is not None
    assert model_mismatch_warning({**fe_scene, "rig": {"kind": "real", "printer": "/dev/ttyUSB0", "daq": "ni"}}) is None
    assert model_mismatch_warning({"rig": {"kind": "dry-run", "daq": "simulated"}}) is None
    assert model_mismatch_warning({}) is None

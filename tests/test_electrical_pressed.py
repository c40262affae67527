"""`campaign check`'s electrical line tells the truth for the protocol's own scene: besides the undeformed worst case,
the presses (its positions x repeats at its depth, through its scene's skin) that would put a pair past the mux rails,
as a warning with numbers; a refused current's fix gives those numbers at the current it allows and at the default."""

import re
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.cli import main
from neatskin.errors import Problem
from neatskin.rig.assembly import daq_config
from neatskin.rig.protocol import load_protocol
from neatskin.rig.railcheck import pressed_rails, pressed_resistance_ohm, with_pressed_figures

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"


def _rail_ohm(amplitude_a: float) -> float:
    """rail / amplitude - 2 R_on - mismatch, from the wiring file as written."""
    e = tomllib.loads((PROTOCOLS / "wiring" / "paper.toml").read_text())["electrical"]
    return (
        min(e["supply_positive_v"], -e["supply_negative_v"]) / amplitude_a - 2 * e["r_on_ohm"] - e["r_on_mismatch_ohm"]
    )


@pytest.fixture(scope="module")
def paper():
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    return protocol, pressed_resistance_ohm(protocol)


def test_pressed_counts_are_exact_at_the_threshold():
    config = DaqConfig(amplitude_a=0.0005)  # the earlier default, 0.5 mA; +-8 V, 210 ohm: 15790 ohm
    rail = _rail_ohm(0.0005)
    r = np.array(
        [
            [1_000.0, rail, np.inf],  # at the rail: past it (>=); a cut pair is no reading
            [1_000.0, np.nextafter(rail, 0.0), 2_000.0],  # one ulp under: inside
            [2 * rail, 3 * rail, 1_000.0],  # two readings past
        ]
    )
    got = pressed_rails(r, config)
    assert (got.presses, got.readings, got.presses_over, got.readings_over) == (3, 8, 2, 3)
    assert got.largest_ohm == 3 * rail and got.readable_ohm == pytest.approx(15_790.0, rel=1e-12)
    # at a quarter of the current the rail moves to 8 V / 0.125 mA - 210 = 63,790 ohm: nothing is past it
    quarter = pressed_rails(r, config, 0.000125)
    assert quarter.readable_ohm == pytest.approx(_rail_ohm(0.000125), rel=1e-12) and quarter.presses_over == 0


def test_the_pressed_share_falls_with_the_current(paper):
    protocol, r = paper
    config = daq_config(protocol)
    shares = [pressed_rails(r, config, a).readings_over for a in (0.002, 0.000925, 0.0005, 0.00025)]
    assert shares == sorted(shares, reverse=True) and shares[0] > shares[-1]
    finite = r[np.isfinite(r)]
    # the paper's 2 mA passes the rails on most pressed readings; 0.5 mA on a few
    assert shares[0] == int((finite >= _rail_ohm(0.002)).sum()) > finite.size / 2
    assert shares[2] == int((finite >= _rail_ohm(0.0005)).sum()) < finite.size / 100


def _paper_at(tmp_path, amplitude: str) -> Path:
    root = tmp_path / "protocols"
    shutil.copytree(PROTOCOLS, root, symlinks=False)
    path = root / "paper.toml"
    text = path.read_text()
    assert "amplitude_a = 0.0002 " in text
    path.write_text(text.replace("amplitude_a = 0.0002 ", f"amplitude_a = {amplitude} "))
    return path


def test_campaign_check_prints_the_pressed_share_as_a_warning(tmp_path, paper, capsys):
    """At 0.5 mA (the protocols' default before the rails were modelled) the FE pinch passes the rails."""
    protocol, r = paper
    assert main(["campaign", "check", str(_paper_at(tmp_path, "0.0005"))]) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if "electrical, pressed" in line)
    finite = np.isfinite(r)
    over = finite & (r >= _rail_ohm(0.0005))
    assert over.any()  # the FE pinch at 3.5 mm passes the rails on some presses at 0.5 mA
    want = f"warning: {int(over.any(axis=1).sum())} of {r.shape[0]} presses"
    assert want in line, line
    assert f"({int(over.sum())} of {int(finite.sum())} readings above 15790 ohm" in line
    assert "100 positions x 28 at 3.5 mm through the scene's fe-kernel skin" in line
    assert "peak 4.32 V" in out  # the undeformed worst case still printed, unchanged


def test_the_default_current_keeps_every_pressed_reading_inside_the_rails(paper, capsys):
    """0.2 mA, the protocols' default: no press of the paper protocol's forecast passes the rails (39,790 ohm), with
    room above the largest pressed R_eq; at 0.25 mA some would (the margin that chose 0.2)."""
    protocol, r = paper
    assert protocol.excitation.amplitude_a == 0.0002 == DaqConfig().amplitude_a
    assert main(["campaign", "check", str(PROTOCOLS / "paper.toml")]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if "electrical, pressed" in line)
    finite = r[np.isfinite(r)]
    assert f"none of {r.shape[0]} presses puts a pair past the rails at 0.2 mA" in line and "warning" not in line
    assert finite.max() < _rail_ohm(0.0002) / 1.15
    assert pressed_rails(r, daq_config(protocol), 0.00025).presses_over > 0


def test_a_refused_current_gets_the_pressed_figures_in_its_fix(tmp_path, paper, capsys):
    protocol, r = paper
    root = tmp_path / "protocols"
    shutil.copytree(PROTOCOLS, root, symlinks=False)
    path = root / "paper.toml"
    path.write_text(path.read_text().replace("amplitude_a = 0.0002 ", "amplitude_a = 0.002 "))
    assert main(["campaign", "check", str(path)]) == 1
    err = capsys.readouterr().err
    assert "the excitation would clip: 2 mA" in err
    finite = np.isfinite(r)
    assert not (finite & (r >= _rail_ohm(0.0002))).any()
    assert re.search(r"lower amplitude_a to 0\.2 mA \(the default: .*?, none of 2800 presses puts a pair past", err), (
        err
    )
    suggested = 0.0002 * 8.0 / protocol.electrical.peak_v  # the largest current the undeformed check allows
    m = re.search(
        r"0\.925 mA is the most that keeps the undeformed skin x the press margin inside them, where (\d+) of", err
    )
    assert m, err
    assert int(m.group(1)) == int((finite & (r >= _rail_ohm(suggested))).any(axis=1).sum()) > r.shape[0] / 3
    assert "more conductive fluid" in err  # the rest of the fix kept


def test_other_problems_pass_through_unchanged(tmp_path):
    """Negative control: a refusal for another reason, or a second problem beside the current's, is left as is."""
    path = PROTOCOLS / "paper.toml"
    other = [Problem("bad depth", str(path), "press.depth_mm", "fix it")]
    assert with_pressed_figures(path, other) == other
    clip = Problem("the excitation would clip: 2 mA x ...", str(path), "excitation.amplitude_a", "lower, or else")
    assert with_pressed_figures(path, [clip, other[0]]) == [clip, other[0]]


def test_a_scene_whose_presses_stay_inside_the_rails_gets_no_warning(capsys):
    """The smoke protocol's parametric pinch raises no pair past 39,790 ohm: the line says so, without a warning."""
    assert main(["campaign", "check", str(PROTOCOLS / "smoke.toml")]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if "electrical, pressed" in line)
    assert "none of 12 presses puts a pair past the rails at 0.2 mA" in line and "warning" not in line

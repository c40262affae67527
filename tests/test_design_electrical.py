"""The design study's electrical check is a campaign protocol's own: a candidate skin the protocol check refuses is
not compliant in the study, and one it accepts is, on a computed example (the paper's 3 x 3 skin, 8 electrodes)."""

import dataclasses
import shutil

import pytest
from conftest import PROTOCOLS

from neatskin.config import files as protocol_schema
from neatskin.config import studyfile
from neatskin.design.candidates import expand
from neatskin.design.evaluate import evaluate_candidate
from neatskin.design.study import study_from_dict
from neatskin.errors import ConfigError
from neatskin.rig.protocol import load_protocol

# the paper's skin: channels of 0.5 ohm m x 15 mm / (2 mm x 1 mm) = 3750 ohm; corner to opposite corner is the
# largest pair, 3/2 x 3750 = 5625 ohm. Peak = I x (5625 x 1.5 press margin + 2 x 100 ohm R_on + 10 ohm mismatch)
# = I x 8647.5 ohm against the +-8 V rails (the lowest limit: compliance 50 V, ADC 10 V / 0.5 = 20 V), so the
# largest current is 8 / 8647.5 = 0.925 mA. 0.9 mA passes (7.78 V), 1.0 mA clips (8.65 V).
PATH_OHM = 5625.0 * 1.5 + 2 * 100.0 + 10.0


def _study(amplitude_a: float):
    return study_from_dict(
        {
            "study": {"name": "paper", "press_grid": 6},
            "layouts": {"sizes": [[3, 3]], "pitch_mm": [15.0]},
            "electrodes": {"counts": [8], "strategies": ["boundary"]},
            "excitation": {"amplitude_a": amplitude_a},
        }
    )


def _protocol_accepts(tmp_path, amplitude_a: float) -> bool:
    root = tmp_path / f"protocols-{amplitude_a:g}"
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    assert "amplitude_a = 0.0002" in text
    (root / "smoke.toml").write_text(text.replace("amplitude_a = 0.0002", f"amplitude_a = {amplitude_a!r}"))
    try:
        protocol = load_protocol(root / "smoke.toml")
    except ConfigError as exc:
        assert [p.field for p in exc.problems] == ["excitation.amplitude_a"], exc
        assert "beyond the mux supply rails (-8 V .. +8 V): 8 V" in str(exc)
        return False
    assert protocol.electrical.peak_v == pytest.approx(amplitude_a * PATH_OHM, rel=1e-12)
    return True


@pytest.mark.parametrize("amplitude_a, accepted", [(0.0009, True), (0.001, False), (0.0005, True), (0.002, False)])
def test_a_candidate_is_compliant_exactly_when_its_protocol_is_accepted(tmp_path, amplitude_a, accepted):
    study = _study(amplitude_a)
    (candidate,) = expand(study)
    row = evaluate_candidate(study, candidate).row
    assert row["undeformed_max_pair_ohm"] == pytest.approx(5625.0, rel=1e-12)
    assert row["peak_voltage_v"] == pytest.approx(amplitude_a * PATH_OHM, rel=1e-12)
    assert (row["electrical_limit_v"], row["electrical_limit"]) == (8.0, "mux supply rails (-8 V .. +8 V)")
    assert row["compliant"] is accepted
    assert _protocol_accepts(tmp_path, amplitude_a) is accepted


def test_at_1_mA_the_old_rule_of_the_study_passed_what_the_protocol_refuses():
    # the study used to compare amplitude x the largest pressed pair R_eq with the rails, without R_on or the margin
    study = _study(0.001)
    (candidate,) = expand(study)
    row = evaluate_candidate(study, candidate).row
    assert 5625.0 < row["max_pair_ohm"] < 8000.0  # a 3.5 mm press raises it, but 1 mA x it stays below 8 V
    assert row["press_margin_covers"] is True  # the protocol's 1.5 x margin covers the simulated presses
    assert row["compliant"] is False


def test_the_study_assumes_the_protocols_defaults():
    protocol_defaults = {
        **{f.name: f.default for f in dataclasses.fields(protocol_schema.ElectricalTable)},
        **{f.name: f.default for f in dataclasses.fields(protocol_schema.Excitation)},
        **{f.name: f.default for f in dataclasses.fields(protocol_schema.AcquisitionSettings)},
    }
    study_defaults = {
        **{f.name: f.default for f in dataclasses.fields(studyfile.StudyExcitationTable)},
        **{f.name: f.default for f in dataclasses.fields(studyfile.StudyAcquisitionTable)},
    }
    shared = ("r_on_ohm", "r_on_mismatch_ohm", "compliance_v", "press_margin", "adc_range_v", "voltage_gain")
    assert {k: study_defaults[k] for k in shared} == {k: protocol_defaults[k] for k in shared}
    assert (
        study_defaults["rails_v"] == protocol_defaults["supply_positive_v"] == -protocol_defaults["supply_negative_v"]
    )

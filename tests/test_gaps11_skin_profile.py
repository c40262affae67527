"""A protocol names a skin profile (`[files] skin_profile`) and the dry run simulates that skin.

The profile is written by hand in `neatskin skin fit`'s format with channel resistances that differ
from the layout's; the dry run's recorded baseline R of every pair must be the network's R_eq of
those channels. A profile for another channel count is one ConfigError before anything moves.
"""

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.errors import ConfigError
from neatskin.rig.folder import load_inputs
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.skin.network import equivalent_resistance

FACTORS = (
    1.3,
    0.8,
    1.0,
    1.15,
    0.9,
    1.25,
    0.7,
    1.05,
    1.2,
    0.85,
    1.1,
    0.95,
)  # per channel, over the paper layout's resistance


def _protocol(folder: Path, profile: str | None) -> Path:
    """smoke.toml in `folder`, its files absolute, naming `profile` (relative) if given."""
    text = (PROTOCOLS / "smoke.toml").read_text()
    for key in ("layout", "wiring", "printer"):
        text = re.sub(
            rf'^{key} = "(.*)"', lambda m, k=key: f'{k} = "{(PROTOCOLS / m.group(1)).resolve()}"', text, flags=re.M
        )
    if profile is not None:
        text = text.replace("[files]\n", f'[files]\nskin_profile = "{profile}"\n')
    path = folder / "protocol.toml"
    path.write_text(text)
    return path


def _profile(path: Path, channels) -> None:
    values = ", ".join(repr(float(v)) for v in channels)
    path.write_text(
        "# skin profile fitted by `neatskin skin fit` to a hand-made test\n[skin_profile]\n"
        f"pinch_gain = 1.2\ndecay_ratio = 0.4\nchannel_resistance_ohm = [{values}]\n"
    )


@pytest.fixture(scope="module")
def profiled_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("profile")
    (base / "skins").mkdir()
    layout = load_protocol(PROTOCOLS / "smoke.toml").layout
    assert layout.n_channels == len(FACTORS)
    channels = layout.channel_resistance_ohm * np.array(FACTORS)
    _profile(base / "skins" / "fitted.toml", channels)
    protocol = load_protocol(_protocol(base, "skins/fitted.toml"))
    folder = base / "campaign"
    run_campaign(protocol, folder, dry_run=True, progress=False, report=False)
    return protocol, folder, channels


def test_protocol_loads_the_profiles_skin(profiled_run):
    protocol, _, channels = profiled_run
    assert protocol.skin_profile_path.name == "fitted.toml"
    assert protocol.referenced_files["skin_profile"] == protocol.skin_profile_path
    skin = protocol.skin_profile
    assert (skin.pinch.pinch_gain, skin.pinch.decay_ratio) == (1.2, 0.4)
    np.testing.assert_allclose(
        skin.baseline_pair_resistance_ohm, equivalent_resistance(protocol.layout, 1.0 / channels), rtol=1e-12
    )


def test_dry_run_records_the_profiles_baseline(profiled_run):
    protocol, folder, channels = profiled_run
    labels = [f"{p.i}_{p.j}" for p in protocol.layout.pairs]
    df = pd.read_parquet(folder / "presses.parquet")
    assert len(df) == 12
    baseline = df[[f"R_ohm_{x}" for x in labels]].to_numpy() - df[[f"dR_ohm_{x}" for x in labels]].to_numpy()
    expected = np.asarray(equivalent_resistance(protocol.layout, 1.0 / channels))
    nominal = np.asarray(equivalent_resistance(protocol.layout, 1.0 / protocol.layout.channel_resistance_ohm))
    assert np.abs(expected / nominal - 1).max() > 0.05  # the profile's skin is not the layout's
    # electronics noise (2 mV on ~0.6 V per sample at the protocol's 0.2 mA) and the ADC step only: each press within
    # 1.25e-3, the mean 3.75e-4 (at 0.5 mA: 5e-4 and 1.5e-4, measured 2.1e-4 and 6e-5; the noise scales as 1 / current)
    np.testing.assert_allclose(baseline, np.tile(expected, (12, 1)), rtol=1.25e-3)
    np.testing.assert_allclose(baseline.mean(axis=0), expected, rtol=3.75e-4)


def test_profile_is_copied_into_inputs_and_resume_reads_the_copy(profiled_run):
    protocol, folder, _ = profiled_run
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["skin_profile"]["path"] == "inputs/skin_profile.toml"
    copy = folder / "inputs" / "skin_profile.toml"
    assert copy.read_bytes() == protocol.skin_profile_path.read_bytes()
    assert manifest["rig"]["skin"]["skin_profile"] == str(protocol.skin_profile_path)
    again = load_inputs(folder)
    assert again.skin_profile_path == copy.resolve()
    np.testing.assert_array_equal(
        again.skin_profile.baseline_pair_resistance_ohm, protocol.skin_profile.baseline_pair_resistance_ohm
    )


def test_without_a_profile_nothing_changes(tmp_path):
    protocol = load_protocol(_protocol(tmp_path, None))
    assert protocol.skin_profile is None and protocol.skin_profile_path is None
    assert "skin_profile" not in protocol.referenced_files


def test_profile_with_wrong_channel_count_is_one_config_error(tmp_path):
    layout = load_protocol(PROTOCOLS / "smoke.toml").layout
    _profile(tmp_path / "short.toml", layout.channel_resistance_ohm[:5])
    with pytest.raises(ConfigError) as info:
        load_protocol(_protocol(tmp_path, "short.toml"))
    (problem,) = info.value.problems
    assert problem.file == str(tmp_path / "short.toml")
    assert problem.field == "skin_profile.channel_resistance_ohm"
    assert problem.message == f"5 channel resistances for layout '{layout.name}', which has 12 channels"
    assert "files.skin_profile" in problem.fix


def test_missing_profile_names_the_protocol_field(tmp_path):
    with pytest.raises(ConfigError) as info:
        load_protocol(_protocol(tmp_path, "nowhere.toml"))
    (problem,) = info.value.problems
    assert (problem.file, problem.field) == (str(tmp_path / "protocol.toml"), "files.skin_profile")
    assert "does not exist" in problem.message

"""End to end on the smoke dry run: a pressed reading past the wiring's mux rails is flagged `clipped:PAIR` in its
parquet row and recorded as +inf, in both signal modes; every other reading is the clean run's.

The smoke protocol's presses stay far inside the paper board's +-8 V, so the test lowers the loaded wiring's rails
to the widest gap between the pairs' pressed node voltages, amplitude x (R + 2 R_on + mismatch), as a deeper
press or a more resistive fluid would raise them (test_gaps11_clipping does the same with the ADC's range).
"""

import dataclasses

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.rig.assembly import daq_config
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign


def _run(protocol, folder) -> pd.DataFrame:
    run_campaign(protocol, folder, dry_run=True, progress=False, report=False)
    return pd.read_parquet(folder / "presses.parquet").sort_values("press_id").reset_index(drop=True)


@pytest.fixture(scope="module", params=["waveforms", "features"])
def runs(request, tmp_path_factory):
    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    protocol = dataclasses.replace(protocol, scene=dataclasses.replace(protocol.scene, signal=request.param))
    labels = [f"{p.i}_{p.j}" for p in protocol.layout.pairs]
    clean = _run(protocol, tmp_path_factory.mktemp("clean") / "campaign")
    pressed = clean[[f"R_ohm_{label}" for label in labels]].to_numpy()
    baseline = pressed - clean[[f"dR_ohm_{label}" for label in labels]].to_numpy()
    e = protocol.wiring.electrical
    series = 2 * e.r_on_ohm + e.r_on_mismatch_ohm
    node_v = protocol.excitation.amplitude_a * (np.maximum(pressed, baseline) + series)  # (presses, pairs)
    values = np.sort(node_v.ravel())
    lo, hi = values.size // 2, values.size - values.size // 20  # the upper half: the baselines stay inside
    k = lo + int(np.argmax(np.diff(values[lo:hi])))
    rail_v = (values[k] + values[k + 1]) / 2
    narrow = dataclasses.replace(e, supply_positive_v=rail_v, supply_negative_v=-rail_v)
    narrowed = dataclasses.replace(protocol, wiring=dataclasses.replace(protocol.wiring, electrical=narrow))
    clipped = _run(narrowed, tmp_path_factory.mktemp("rails") / "campaign")
    gap = (values[k + 1] - values[k]) / rail_v
    return narrowed, labels, clean, clipped, node_v, rail_v, gap


def test_the_rails_reach_the_dry_daq(runs):
    narrowed, *_, rail_v, _ = runs
    config = daq_config(narrowed)
    assert (config.rail_positive_v, config.rail_negative_v, config.mux_series_ohm) == (rail_v, -rail_v, 210.0)


def test_readings_past_the_rails_are_flagged_and_recorded_as_no_value(runs):
    narrowed, labels, clean, clipped, node_v, rail_v, gap = runs
    assert gap > 0.002  # no reading near the rail: noise (~1e-3 V on volts) cannot decide it
    assert all(flags.size == 0 for flags in clean["flags"])
    over = node_v > rail_v
    assert 0 < over.sum() < over.size / 2
    names = [label.replace("_", "-") for label in labels]
    expected = [[f"clipped:{name}" for name, o in zip(names, row) if o] for row in over]
    assert [list(flags) for flags in clipped["flags"]] == expected
    got = clipped[[f"R_ohm_{label}" for label in labels]].to_numpy()
    want = clean[[f"R_ohm_{label}" for label in labels]].to_numpy()
    assert np.isinf(got[over]).all()
    assert np.isinf(clipped[[f"dR_ohm_{label}" for label in labels]].to_numpy()[over]).all()
    # every other reading is the clean run's: bit for bit in waveforms mode (the clamp touches only the samples past
    # the rail); in features mode a press with a pair near the rail goes the waveform path, new draws of one law
    if narrowed.scene.signal == "waveforms":
        np.testing.assert_array_equal(got[~over], want[~over])
    else:
        np.testing.assert_allclose(got[~over], want[~over], rtol=2e-3)

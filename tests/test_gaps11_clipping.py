"""A press whose readings clip is flagged `clipped:PAIR` in its parquet row, end to end on the smoke dry run.

The dry run's DAQ takes the protocol's ADC range and voltage gain, so a protocol whose range is too
small for some pairs clips exactly those. The electrical check refuses such a protocol, so the test
narrows the range of an already loaded one (as a press deeper than the check's margin would).
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


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The smoke run as is, and again with the voltage range cut between the pairs' peak voltages."""
    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    labels = [f"{p.i}_{p.j}" for p in protocol.layout.pairs]
    clean = _run(protocol, tmp_path_factory.mktemp("clean") / "campaign")
    pressed = clean[[f"R_ohm_{label}" for label in labels]].to_numpy()
    baseline = pressed - clean[[f"dR_ohm_{label}" for label in labels]].to_numpy()
    # the largest sample of A sin(2 pi f n / rate): at 1 kHz and 10 kHz the phases are multiples of 36 deg,
    # so the sampled peak is A sin(72 deg), not A
    f_hz, rate_hz = protocol.excitation.frequency_hz, protocol.acquisition.rate_hz
    sampled = np.abs(np.sin(2 * np.pi * f_hz * np.arange(int(rate_hz / f_hz)) / rate_hz)).max()
    assert sampled == pytest.approx(np.sin(np.radians(72)), rel=1e-12)
    peak_v = np.maximum(pressed, baseline) * protocol.excitation.amplitude_a * sampled  # (presses, pairs)
    # the limit in the widest gap between peak voltages in their middle half: no reading sits near it
    values = np.sort(peak_v.ravel())
    lo, hi = values.size // 4, 3 * values.size // 4
    k = lo + int(np.argmax(np.diff(values[lo:hi])))
    limit_v = (values[k] + values[k + 1]) / 2
    gap = (values[k + 1] - values[k]) / limit_v
    acquisition = dataclasses.replace(protocol.acquisition, adc_range_v=limit_v * protocol.acquisition.voltage_gain)
    narrow = dataclasses.replace(protocol, acquisition=acquisition)
    clipped = _run(narrow, tmp_path_factory.mktemp("clipped") / "campaign")
    return narrow, labels, clean, clipped, peak_v, limit_v, gap


def test_the_dry_daq_takes_the_protocols_limits(runs):
    narrow, *_, limit_v, _ = runs
    config = daq_config(narrow)
    assert config.voltage_range_v == narrow.acquisition.adc_range_v
    assert config.voltage_gain == narrow.acquisition.voltage_gain == 0.5
    assert config.compliance_v == narrow.excitation.compliance_v == 50.0
    assert config.voltage_limit_v == pytest.approx(limit_v, rel=1e-12)


def test_clipping_pairs_are_named_in_their_rows(runs):
    _, labels, clean, clipped, peak_v, limit_v, gap = runs
    assert gap > 0.002  # the limit is clear of every reading (noise is ~1e-3 V on volts)
    assert all(flags.size == 0 for flags in clean["flags"])
    assert len(clipped) == 12
    names = [label.replace("_", "-") for label in labels]  # the row's flags name a pair "i-j"
    expected = [[f"clipped:{name}" for name, v in zip(names, row) if v > limit_v] for row in peak_v]
    got = [[f for f in flags if f.startswith("clipped:")] for flags in clipped["flags"]]
    assert got == expected
    n_flagged = sum(bool(row) for row in expected)
    assert 0 < sum(len(row) for row in expected) < 12 * len(labels)
    assert n_flagged > 0
    # nothing else went wrong: the only flags are the clipping ones
    assert [list(flags) for flags in clipped["flags"]] == expected


def test_unclipped_pairs_read_what_the_clean_run_read(runs):
    _, labels, clean, clipped, peak_v, limit_v, _ = runs
    columns = [f"R_ohm_{label}" for label in labels]
    fine = peak_v < limit_v
    got, want = clipped[columns].to_numpy(), clean[columns].to_numpy()
    # same noise draws; only the ADC step differs (the narrow range rounds finer): a few 1e-5 of R
    np.testing.assert_allclose(got[fine], want[fine], rtol=1e-4)
    # a clipped pair is no value: its peaks are cut off, so V / I would read low; the row records +inf, as a cut
    # pair's (acquisition.pressvalues), which the baselines saturate instead of learning a wrong finite dR
    assert np.isinf(got[~fine]).all() and np.isfinite(want[~fine]).all()

"""The mux rails bound what the rig reads: a pair whose switch node, amplitude x (R + 2 R_on + mismatch), reaches a
rail is clamped by the switch and flagged CLIPPED (the demodulator, the simulated DAQ's waveform and features paths),
recorded as no value (+inf, as a cut pair's), and the forecast's presses treat it as unreadable. The threshold is
exact: rail / amplitude - series, from the wiring file's own numbers; a pair 0.1 % under it reads as before."""

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq.base import Acquisition, DaqConfig
from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.estimates import PairFlag
from neatskin.acquisition.pressvalues import press_values
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.baselines.dataset import SATURATION_FACTOR
from neatskin.rig.assembly import daq_config
from neatskin.rig.protocol import load_protocol
from neatskin.rig.simcampaign import simulate_presses
from neatskin.sim.daq import NoiseModel, SimulatedDAQ

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"
WIRING = PROTOCOLS / "wiring" / "paper.toml"
AMPLITUDE_A = 0.0002  # the protocols' and DaqConfig's default
OVER, UNDER, FAR = 1, 2, 3  # the pairs set just over, just under and at twice the rail


def _wiring_numbers():
    """The rail and the series resistance as the wiring file writes them, read without the package."""
    e = tomllib.loads(WIRING.read_text())["electrical"]
    rail_v = min(e["supply_positive_v"], -e["supply_negative_v"])
    return rail_v, 2 * e["r_on_ohm"] + e["r_on_mismatch_ohm"]


RAIL_V, SERIES_OHM = _wiring_numbers()
RAIL_OHM = RAIL_V / AMPLITUDE_A - SERIES_OHM  # 8 V / 0.2 mA - 210 ohm = 39790 ohm


def _resistances() -> np.ndarray:
    r = np.linspace(2_000.0, 9_000.0, 28)
    r[OVER] = RAIL_OHM * 1.001
    r[UNDER] = RAIL_OHM * 0.999
    r[FAR] = RAIL_OHM * 2.0
    return r


@pytest.fixture(scope="module")
def sweep(paper_layout):
    return build_sweep(load_wiring(WIRING, paper_layout))


@pytest.fixture(scope="module")
def config(paper_layout) -> DaqConfig:
    e = load_wiring(WIRING, paper_layout).electrical
    return DaqConfig(
        amplitude_a=AMPLITUDE_A,
        rail_positive_v=e.supply_positive_v,
        rail_negative_v=e.supply_negative_v,
        mux_series_ohm=2 * e.r_on_ohm + e.r_on_mismatch_ohm,
    )


def constant(r):
    return lambda t: np.broadcast_to(r, (len(t), r.shape[0]))


def test_the_wiring_rails_reach_the_protocols_daq_config():
    config = daq_config(load_protocol(PROTOCOLS / "paper.toml"))
    assert (config.rail_positive_v, config.rail_negative_v, config.mux_series_ohm) == (8.0, -8.0, SERIES_OHM)
    assert config.amplitude_a == AMPLITUDE_A
    assert config.rail_ohm == pytest.approx(39_790.0, rel=1e-12) == RAIL_OHM
    # the rails, not the ADC (10 V / 0.5 = 20 V: 100 kohm) nor the compliance (50 V), bound the paper rig's readings
    assert config.readable_ohm == config.rail_ohm
    assert DaqConfig().amplitude_a == AMPLITUDE_A  # the default is the consistent current, not the paper's 2 mA


def _clamped_acquisition(config: DaqConfig, sweep, r: np.ndarray) -> Acquisition:
    """A synthetic acquisition built here, not by the simulator: the galvanostat's sine, the switch node held at the
    rail, V across the pair = node x R / (R + series), the current monitor reading the galvanostat's current."""
    n = 2 * sweep.n_samples
    index = np.arange(n, dtype=np.int64)
    pair = np.tile(sweep.pair_of_sample, 2)
    connected = pair >= 0
    rp = r[np.maximum(pair, 0)]
    i = config.amplitude_a * np.sin(2 * np.pi * index / config.samples_per_period) * connected
    node = np.clip(i * (rp + config.mux_series_ohm), -RAIL_V, RAIL_V)
    v = node * rp / (rp + config.mux_series_ohm)
    samples = np.stack([v, i, np.zeros(n)], axis=1)
    return Acquisition(samples, index, config, 2)


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_the_demodulator_flags_a_waveform_clamped_at_the_rail(config, sweep, method):
    r = _resistances()
    est = demodulate(_clamped_acquisition(config, sweep, r), sweep, method)
    clipped = (est.flags & PairFlag.CLIPPED) != 0
    assert clipped[:, [OVER, FAR]].all()
    assert not clipped[:, UNDER].any() and (est.flags[:, UNDER] == 0).all()
    others = np.setdiff1d(np.arange(28), [OVER, FAR])
    assert (est.flags[:, others] == 0).all()
    np.testing.assert_allclose(est.resistance_ohm[:, others], np.broadcast_to(r[others], (2, 26)), rtol=1e-9)
    # the clamped reading is wrong (the current no longer all flows through the skin): it reads low
    assert (est.resistance_ohm[:, FAR] < 0.9 * r[FAR]).all()


@pytest.mark.parametrize("method", ["rms", "lockin"])
def test_without_the_rails_the_same_waveforms_are_not_flagged(config, sweep, method):
    """Negative control: the flag comes from the rails, not from the size of the reading."""
    r = _resistances()
    r[[OVER, FAR]] = RAIL_OHM * 0.5  # no clamp in the waveform, the rails at +-20 V
    wide = dataclasses.replace(config, rail_positive_v=20.0, rail_negative_v=-20.0)
    est = demodulate(_clamped_acquisition(wide, sweep, r), sweep, method)
    assert (est.flags == 0).all()


@pytest.mark.parametrize("path", ["waveforms", "features"])
@pytest.mark.parametrize("noise", [NoiseModel.none(), NoiseModel()], ids=["ideal", "noisy"])
def test_the_simulated_daq_clamps_and_flags_in_both_signal_modes(config, sweep, paper_layout, path, noise):
    r = _resistances()
    daq = SimulatedDAQ(config, constant(r), noise=noise)
    rng = np.random.default_rng(3)
    if path == "waveforms":
        est = demodulate(daq.acquire(sweep, 2, rng=rng), sweep, "lockin")
    else:
        est = daq.estimate_sweep(sweep, rng, method="lockin", n_sweeps=2)
    clipped = (est.flags & PairFlag.CLIPPED) != 0
    assert clipped[:, [OVER, FAR]].all()
    assert not clipped[:, UNDER].any()
    assert not clipped[:, np.setdiff1d(np.arange(28), [OVER, FAR])].any()
    rtol = 1e-9 if noise == NoiseModel.none() else 1e-3
    np.testing.assert_allclose(est.resistance_ohm[:, UNDER], r[UNDER], rtol=rtol)
    # the switch clamped FAR's voltage: the skin took rail / (R + series) of the galvanostat's current, V / I reads low
    assert (est.resistance_ohm[:, FAR] < 0.9 * r[FAR]).all()
    # the press's row: a clipped pair is no value (+inf, as a cut pair's), named in the flags
    n = est.windows.shape[0]
    marks = {"contact": int(est.windows[n // 2, 0, 0]), "hold_start": 0, "hold_end": int(est.windows[-1, -1, 1])}
    labels = [f"{p.i}-{p.j}" for p in paper_layout.pairs]
    values = press_values(est, marks, labels)
    assert np.isinf(values.resistance_ohm[[OVER, FAR]]).all() and np.isfinite(values.resistance_ohm[UNDER])
    assert {f"clipped:{labels[k]}" for k in (OVER, FAR)} <= set(values.flags)
    assert not any(f.endswith(f":{labels[UNDER]}") for f in values.flags)


def test_features_mode_takes_the_fast_path_only_clear_of_the_rail(config, sweep, monkeypatch):
    """A press whose pairs are all 0.1 % under the rail is not sent to the waveform path (noise off): the fast
    path's verdict is the waveform path's there; one reading over it is."""
    calls = []
    daq = SimulatedDAQ(config, constant(np.full(28, RAIL_OHM * 0.999)), noise=NoiseModel.none())
    original = daq.acquire
    monkeypatch.setattr(daq, "acquire", lambda *a, **k: calls.append(1) or original(*a, **k))
    est = daq.estimate_sweep(sweep, np.random.default_rng(0), method="rms")
    assert not calls and (est.flags == 0).all()
    daq.pair_resistance_ohm = constant(np.full(28, RAIL_OHM * 1.001))
    est = daq.estimate_sweep(sweep, np.random.default_rng(0), method="rms")
    assert calls and (est.flags == PairFlag.CLIPPED).all()


class _Skin:
    """A skin whose pressed pairs read given R wherever and however deep the probe lands."""

    resistivity_tempco_per_k = -0.02

    def __init__(self, pressed: np.ndarray, baseline: np.ndarray) -> None:
        self.pressed, self.baseline_pair_resistance_ohm = pressed, baseline

    def pair_resistance_ohm(self, x, y, depth, resistivity_factor=None):
        return np.broadcast_to(self.pressed, (len(np.atleast_1d(x)), self.pressed.size)).copy()


def test_the_forecasts_presses_treat_a_reading_past_the_rail_as_unreadable():
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    r = _resistances()
    base = np.full(28, 3_000.0)
    presses = simulate_presses(
        protocol, np.array([[0.0, 0.0], [1.0, 1.0]]), 3, 3.5, 7, np.zeros(28), skin=_Skin(r, base), interval_s=0.0
    )
    dr = r - base
    clear = np.setdiff1d(np.arange(28), [OVER, FAR])
    np.testing.assert_allclose(presses.features[:, clear], np.broadcast_to(dr[clear], (6, 26)), rtol=1e-12)
    # OVER and FAR are no value: each column saturated (no finite dR in it: 2 x the largest finite |dR| overall)
    saturation = SATURATION_FACTOR * np.abs(dr[clear]).max()
    np.testing.assert_allclose(presses.features[:, [OVER, FAR]], saturation, rtol=1e-12)
    assert presses.features[0, UNDER] == pytest.approx(dr[UNDER], rel=1e-12)


@pytest.mark.parametrize("path", ["waveforms", "features"])
def test_a_pair_cut_off_still_reads_as_before_beside_the_rails(config, sweep, path):
    """A channel pinched shut (R = inf) keeps its model: no current, OPEN_CIRCUIT | CLIPPED, R and its uncertainty
    +inf, in both paths; the rails do not turn it into a finite reading."""
    r = _resistances()
    r[[5, 9]] = np.inf
    daq = SimulatedDAQ(config, constant(r), noise=NoiseModel())
    rng = np.random.default_rng(5)
    if path == "waveforms":
        est = demodulate(daq.acquire(sweep, 2, rng=rng), sweep, "rms")
    else:
        est = daq.estimate_sweep(sweep, rng, method="rms", n_sweeps=2)
    assert (est.flags[:, [5, 9]] == PairFlag.OPEN_CIRCUIT | PairFlag.CLIPPED).all()
    assert np.isinf(est.resistance_ohm[:, [5, 9]]).all() and np.isinf(est.uncertainty_ohm[:, [5, 9]]).all()
    assert (est.flags[:, OVER] == PairFlag.CLIPPED).all()

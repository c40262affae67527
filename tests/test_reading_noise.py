"""The derived reading noise of one press's dR (rig.physlimitnoise, which rig.physlimit and simcampaign use) against
what a dry run on an ideal scene repeats to, through the real recording path: the estimates each press averages
are those the recorder's press values select (acquisition.pressvalues.sweeps_used), and the spread over presses at
one position matches the derived std within the chi-square interval of the sample; the former count (6 baseline,
2 pressed whole sweeps) and a doubled noise fail the same test."""

import dataclasses

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

import neatskin.acquisition.record as record_module
from neatskin.acquisition.pressvalues import sweeps_used
from neatskin.config.scene import PRESETS, SCENE_KNOBS, Scene
from neatskin.rig.dryrig import SKIN_WORKER_ENV, dry_scene
from neatskin.rig.physlimitnoise import (
    DRAWS,
    dr_noise_std_ohm,
    estimate_var_ohm2,
    nominal_marks,
    press_estimate_counts,
    press_windows,
)
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.rig.simcampaign import CampaignSize, with_size
from neatskin.sim.daq import NoiseModel, SimulatedDAQ
from neatskin.sim.dryscene import dry_skin, interface_noise

PRESSES = 40  # at one position: 28 x 39 = 1,092 degrees of freedom, a 99.9 % interval of about +-14 % in variance
CONFIDENCE = 0.999


def ideal_paper(presses: int, *, noise: bool = True):
    """protocols/paper.toml (its FE-kernel skin, DAQ and 0.2 mA) with every variability knob of the ideal preset
    (no placement error, depth jitter, drift, dents or fabrication spread), one position pressed `presses` times."""
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    fields = {f.name: getattr(protocol.scene, f.name) for f in dataclasses.fields(Scene)}
    scene = Scene(**{**fields, **{k: PRESETS["ideal"][k] for k in SCENE_KNOBS}, "preset": "ideal", "noise": noise})
    return with_size(dataclasses.replace(protocol, scene=scene), CampaignSize(1, presses, 3.5))


def dry_run(protocol, folder, monkeypatch):
    """The dry run's presses (inline: the recorder's own process computes each press's values) and, per press, the
    marks and the per-pair counts of the estimates its values averaged, as the real path selected them."""
    monkeypatch.setenv(SKIN_WORKER_ENV, "off")
    seen = []
    real = record_module.press_values

    def spy(estimates, marks, labels):
        baseline, pressed = sweeps_used(estimates.windows, marks)  # both in the acquisition's global sample index
        seen.append((dict(marks), int(estimates.windows[0, 0, 0]), baseline.sum(0), pressed.sum(0)))
        return real(estimates, marks, labels)

    monkeypatch.setattr(record_module, "press_values", spy)
    run_campaign(protocol, folder, dry_run=True, progress=False, report=False)
    return pd.read_parquet(folder / "presses.parquet"), seen


@pytest.fixture(scope="module")
def repeated(tmp_path_factory):
    protocol = ideal_paper(PRESSES)
    with pytest.MonkeyPatch.context() as monkeypatch:
        presses, seen = dry_run(protocol, tmp_path_factory.mktemp("noise") / "run", monkeypatch)
    return protocol, presses, seen


def derived_at_the_position(protocol, presses):
    """The derived std per pair at the run's one position, and the per-sweep variances it came from."""
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    daq = SimulatedDAQ(dry.daq, lambda t: None, noise=interface_noise(NoiseModel(), dry.scene))
    x, y = presses.x_mm.to_numpy()[:1], presses.y_mm.to_numpy()[:1]
    depth = np.array([protocol.press.press.depth_mm])
    std = dr_noise_std_ohm(protocol, plan, skin, daq, x, y, depth)[0]
    states = np.vstack([skin.baseline_pair_resistance_ohm, skin.pair_resistance_ohm(x, y, depth)])
    acq = protocol.acquisition
    var = estimate_var_ohm2(daq, plan, states, protocol.seed, acq.demodulation, acq.window)
    return std, var, plan


def repeatability_ratio(presses: pd.DataFrame, derived_std: np.ndarray) -> tuple[float, tuple[float, float]]:
    """The pooled ratio mean_j s_j^2 / sigma_j^2 of the measured variance over presses (ddof 1) to the derived one,
    pairs pooled, and its interval at CONFIDENCE: under the derived noise the measured side is chi-square with
    pairs x (presses - 1) degrees of freedom and the derived side's Monte Carlo variance (DRAWS draws a state)
    adds pairs x (DRAWS - 1) more, so the ratio is F-distributed (both sides' sample sizes set the tolerance)."""
    dr = presses.filter(like="dR_ohm_").to_numpy()
    measured = dr.var(axis=0, ddof=1)
    ratio = float(np.mean(measured / derived_std**2))
    dof_measured = dr.shape[1] * (len(dr) - 1)
    dof_derived = dr.shape[1] * (DRAWS - 1)
    tail = (1 - CONFIDENCE) / 2
    low, high = stats.f.ppf([tail, 1 - tail], dof_measured, dof_derived)
    return ratio, (float(low), float(high))


def test_the_counts_are_those_the_recorder_averaged(repeated):
    """Every press of the dry run was marked where nominal_marks puts it, and its values averaged, per pair, the
    estimates press_estimate_counts counts: on paper.toml 6 baseline and 3 or 4 pressed (the pair's live window
    inside the 1.2 s hold), where the former count took 2 (whole sweeps in the hold, minus one)."""
    protocol, presses, seen = repeated
    plan = build_plan(protocol)
    n_baseline, n_pressed = press_estimate_counts(plan)
    assert len(seen) == PRESSES
    for marks, first_window, baseline, pressed in seen:
        first = first_window - int(plan.sweep.live_windows[0, 0])  # the recording's first sample
        assert {k: marks[k] - first for k in nominal_marks(plan)} == nominal_marks(plan)
        np.testing.assert_array_equal(baseline, n_baseline)
        np.testing.assert_array_equal(pressed, n_pressed)
    # the arithmetic oracle: sweeps of 3,416 samples, pair j live on [22 + 122 j, 122 + 122 j) of its sweep; the
    # baseline ends at contact (sample 20,500), the hold spans [38,200, 50,200)
    sweep = plan.sweep
    assert (sweep.n_samples, nominal_marks(plan)) == (3416, {"contact": 20500, "hold_start": 38200, "hold_end": 50200})
    start, stop = sweep.live_windows[:, 0], sweep.live_windows[:, 1]
    np.testing.assert_array_equal(start, 22 + 122 * np.arange(28))
    expected_pressed = np.floor((50200 - stop) / 3416) - np.ceil((38200 - start) / 3416) + 1
    np.testing.assert_array_equal(n_pressed, expected_pressed)
    np.testing.assert_array_equal(n_baseline, np.floor((20500 - stop) / 3416) + 1)
    assert sorted(set(n_pressed.tolist())) == [3, 4] and set(n_baseline.tolist()) == {6}


def test_the_ideal_scene_repeats_to_the_derived_noise_and_the_former_count_fails(repeated):
    protocol, presses, _ = repeated
    derived, var, plan = derived_at_the_position(protocol, presses)
    ratio, (low, high) = repeatability_ratio(presses, derived)
    assert low < ratio < high, (ratio, low, high)
    # negative controls through the same test: the former count (6 baseline and 2 pressed sweeps for every pair:
    # int(descend_s // sweep_s) and int(hold_s // sweep_s) - 1) and the derived noise doubled are both rejected
    sweep_s = plan.sweep.duration_s
    phases = np.median(plan.phase_s, axis=0)
    former = np.sqrt(var[0] / int(phases[1] // sweep_s) + var[1] / (int(plan.hold_s // sweep_s) - 1))
    assert (int(phases[1] // sweep_s), int(plan.hold_s // sweep_s) - 1) == (6, 2)
    for wrong in (former, 2 * derived):
        wrong_ratio, (low, high) = repeatability_ratio(presses, wrong)
        assert not low < wrong_ratio < high, wrong_ratio


def test_the_ideal_scene_has_no_spread_but_the_noise(tmp_path, monkeypatch):
    """Without measurement noise the same presses at one position read the same dR to the bit: the repeatability
    of the ideal scene measures the electronics alone (no placement, depth, drift, dent or skin spread)."""
    presses, _ = dry_run(ideal_paper(4, noise=False), tmp_path / "quiet", monkeypatch)
    dr = presses.filter(like="dR_ohm_").to_numpy()
    assert len(dr) == 4 and np.isfinite(dr).all() and np.abs(dr).max() > 1.0
    np.testing.assert_array_equal(dr, np.broadcast_to(dr[0], dr.shape))


@given(
    sweep_samples=st.integers(200, 5000),
    live=st.integers(1, 150),
    offsets=st.lists(st.floats(0, 1), min_size=1, max_size=6),
    n_sweeps=st.integers(1, 30),
    contact=st.integers(0, 60_000),
    hold_start=st.integers(0, 60_000),
    hold=st.integers(0, 30_000),
)
def test_the_selection_counts_every_live_window_inside_its_span(
    sweep_samples, live, offsets, n_sweeps, contact, hold_start, hold
):
    """sweeps_used counts, per pair, the live windows [o + k S, o + k S + live) of the recording's sweeps that end
    by `contact` (baseline) or lie in [hold_start, hold_end] (pressed): the closed forms floor / ceil of the
    window's position, clipped to the sweeps recorded."""
    live = min(live, sweep_samples)
    start = np.floor(np.asarray(offsets) * (sweep_samples - live)).astype(int)
    windows = np.arange(n_sweeps)[:, None, None] * sweep_samples + np.stack([start, start + live], axis=1)[None]
    marks = {"contact": contact, "hold_start": hold_start, "hold_end": hold_start + hold}
    baseline, pressed = sweeps_used(windows, marks)
    last = n_sweeps - 1
    first_in = np.clip(np.ceil((hold_start - start) / sweep_samples), 0, None)
    last_in = np.clip(np.floor((hold_start + hold - start - live) / sweep_samples), None, last)
    np.testing.assert_array_equal(pressed.sum(0), np.clip(last_in - first_in + 1, 0, None))
    last_before = np.clip(np.floor((contact - start - live) / sweep_samples), -1, last)
    np.testing.assert_array_equal(baseline.sum(0), last_before + 1)


def test_the_nominal_windows_are_the_dry_runs():
    """press_windows is the features path's window layout of a press's recording (first sample 0)."""
    protocol = load_protocol(PROTOCOLS / "paper.toml")
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    base = np.asarray(skin.baseline_pair_resistance_ohm, float)
    daq = SimulatedDAQ(dry.daq, lambda t: np.broadcast_to(base, (len(t), base.size)), noise=NoiseModel())
    est = daq.estimate_sweep(plan.sweep, np.random.default_rng(0), 0.0, method="rms", n_sweeps=plan.n_sweeps)
    np.testing.assert_array_equal(press_windows(plan), est.windows)


def test_the_physical_limit_and_the_simulated_campaigns_take_this_noise(monkeypatch):
    """One derivation: physical_limit_table's bounds come from dr_noise_std_ohm's figure (doubling it doubles the
    electronics-only bound, a Cramér-Rao bound being linear in the noise std), and simcampaign's pair noise is the
    same function at the layout's centre."""
    import neatskin.rig.physlimit as physlimit
    from neatskin.rig.simcampaign import pair_noise_std_ohm

    protocol = ideal_paper(1)
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    daq = SimulatedDAQ(dry.daq, lambda t: None, noise=interface_noise(NoiseModel(), dry.scene))
    seen = []

    def scaled(factor):
        def noise(*args, **kwargs):
            std = dr_noise_std_ohm(*args, **kwargs)
            seen.append(std)
            return factor * std

        return noise

    monkeypatch.setattr(physlimit, "dr_noise_std_ohm", scaled(1.0))
    once = physlimit.physical_limit_table(protocol, plan, skin, daq).to_pandas()
    monkeypatch.setattr(physlimit, "dr_noise_std_ohm", scaled(2.0))
    twice = physlimit.physical_limit_table(protocol, plan, skin, daq).to_pandas()
    assert len(seen) == 2 and seen[0].shape == (1, 28)
    np.testing.assert_array_equal(seen[0], seen[1])
    assert np.isfinite(once.crb_mm).all() and (once.crb_mm > 0).all()
    np.testing.assert_allclose(twice.crb_mm, 2 * once.crb_mm, rtol=1e-9)
    x0, y0, x1, y1 = protocol.layout.bounds_mm
    centre = dr_noise_std_ohm(
        protocol, plan, skin, daq, np.array([(x0 + x1) / 2]), np.array([(y0 + y1) / 2]), np.array([3.5])
    )[0]
    np.testing.assert_array_equal(pair_noise_std_ohm(protocol), centre)

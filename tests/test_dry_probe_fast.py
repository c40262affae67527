"""The dry probe's shortcuts give the bits of the straightforward evaluation: positions by slices of the sample
clock, skin and force only where the probe may touch, states deduplicated by depth, the RMS moments' per-phase
table, and residual dents computed per block of presses (pure in the press id, so resume stays exact)."""

import numpy as np
import pytest
from conftest import PROTOCOLS
from hypothesis import example, given, settings
from hypothesis import strategies as st

from neatskin.gcode.calibration import Calibration
from neatskin.layout import load_layout
from neatskin.sim.depthtrace import below_runs, z_mm
from neatskin.sim.dryprobe import DryProbe, PressConditions, _positions_mm, _unique_states
from neatskin.sim.moments import _sine, _weighted_sin2_sums
from neatskin.sim.motion import Segment, positions_mm, segment_fraction
from neatskin.skin.model import SkinModel

SURFACE_Z_MM = 5.5


@pytest.fixture(scope="module")
def skin():
    return SkinModel(
        load_layout(PROTOCOLS / "skins" / "paper.toml"),
        channel_height_factor=tuple(np.linspace(0.9, 1.1, 12)),
        displaced_fluid_fraction=0.5,
    )


def press_segments(x=112.3, y=101.7, drag_mm=0.0):
    """A press as the printer runs it, on the press's own clock: a zero-length start, descend to contact, on to
    3.5 mm at 2 mm/s, a 1.2 s dwell (a gap between moves), lift (dragged sideways by drag_mm); then a travel."""
    top, contact, deep = (x, y, 15.5), (x, y, SURFACE_Z_MM), (x, y, 2.0)
    return [
        Segment(0.0, 0.0, top, top, 100.0, 500.0, False, 0.0),
        Segment(0.0, 2.05, top, contact, 5.0, 100.0, False, 2.05),
        Segment(2.05, 3.82, contact, deep, 2.0, 100.0, False, 1.77),
        Segment(5.02, 7.77, deep, (x + drag_mm, y, 15.5), 5.0, 100.0, False, 2.75),
        Segment(7.77, 8.0, top, (x + 3.0, y - 1.0, 15.5), 1.0, 1.0, True, 0.23),
    ]


def test_positions_by_slices_are_the_bits_of_positions_mm():
    segments = press_segments()
    times = np.sort(np.concatenate([np.linspace(-0.5, 9.0, 4001), [0.0, 2.05, 3.82, 5.02, 7.77, 8.0]]))
    full = positions_mm(segments, times)
    assert _positions_mm(segments, times).tobytes() == full.tobytes()
    assert _positions_mm(segments, times, slice(2, 3)).tobytes() == np.ascontiguousarray(full[:, 2:]).tobytes()
    shuffled = np.random.default_rng(0).permutation(times)  # not a sample clock: positions_mm itself
    assert _positions_mm(segments, shuffled).tobytes() == positions_mm(segments, shuffled).tobytes()


@settings(max_examples=200, deadline=None)
@given(
    length=st.floats(0.001, 200.0),
    feed=st.floats(0.1, 300.0),
    accel=st.floats(1.0, 5000.0),
    n=st.integers(1, 400),
    seed=st.integers(0, 2**32 - 1),
)
def test_a_move_on_a_sample_clock_by_slices_is_the_bits_of_the_masks(length, feed, accel, n, seed):
    """segment_fraction(ordered=True), each phase (accelerate, cruise, brake) one slice of an increasing clock,
    gives the mask version's bits, the phase boundaries themselves among the times."""
    seg = Segment(0.0, 1.0, (0.0, 0.0, 0.0), (length, 0.0, 0.0), feed, accel, False, None)
    v = min(feed, float(np.sqrt(accel * length)))
    t_a = v / accel
    t_c = max(0.0, (length - 2 * v * v / (2 * accel)) / v)
    total = 2 * t_a + t_c
    rng = np.random.default_rng(seed)
    tau = np.sort(np.concatenate([rng.uniform(0.0, 1.2 * total, n), [0.0, t_a, t_a + t_c, total, 2 * total]]))
    want = segment_fraction(seg, tau)
    assert segment_fraction(seg, tau, ordered=True).tobytes() == want.tobytes()


@settings(max_examples=150, deadline=None)
@given(
    heights=st.lists(st.floats(0.0, 20.0), min_size=2, max_size=6),
    drift_mm=st.floats(-3.0, 3.0),
    feed=st.floats(0.5, 50.0),
    accel=st.floats(5.0, 2000.0),
    linear=st.booleans(),
    gap_s=st.floats(0.0, 0.5),
    contact_z_mm=st.floats(1.0, 12.0),
    seed=st.integers(0, 2**32 - 1),
)
@example([0.0, 1.0], 0.0, 1.0, 5.5, False, 0.0, 1.0, 0)  # a rise ending at the height: its rest rounds 1 ulp below
@example([6.0, 1.1], 0.0, 1.0, 5.0, False, 0.0, 1.1, 0)  # a descent ending at the height
def test_the_z_path_and_its_runs_give_the_bits_of_positions_mm(
    heights, drift_mm, feed, accel, linear, gap_s, contact_z_mm, seed
):
    """depthtrace.z_mm is positions_mm's z column bit for bit (trapezoid, linear and still moves, rests between
    them, times before the first move); below_runs leaves out only times at which that z is at or above the
    contact height."""
    segments, t = [], 0.0
    for k, (z0, z1) in enumerate(zip(heights, heights[1:])):
        p0, p1 = (10.0 + k * drift_mm, 5.0, z0), (10.0 + (k + 1) * drift_mm, 5.0, z1)
        length = float(np.linalg.norm(np.subtract(p1, p0)))
        duration = length / feed + feed / accel if length else 0.0
        segments.append(Segment(t, t + duration, p0, p1, feed, accel, linear and k % 2 == 0, duration))
        t += duration + gap_s
    rng = np.random.default_rng(seed)
    times = np.sort(np.concatenate([rng.uniform(-0.3, t + 0.5, 700), [s.t0_s for s in segments]]))
    want = positions_mm(segments, times)[:, 2]
    assert z_mm(segments, times).tobytes() == want.tobytes()
    kept = np.zeros(times.size, dtype=bool)
    for lo, hi in below_runs(segments, times, contact_z_mm):
        kept[lo:hi] = True
    assert np.all(want[~kept] >= contact_z_mm)


def test_unique_states_sort_and_invert_as_numpy_unique_rows():
    rng = np.random.default_rng(1)
    depth = rng.choice(np.round(rng.uniform(0.001, 3.5, 40), 6), 300)
    held = np.column_stack([np.full(300, 12.345678), np.full(300, -0.5), depth])
    moving = held.copy()
    moving[::7, 0] += 0.25  # a press that drags sideways: the row sort
    for states in (held, moving):
        unique, inverse = _unique_states(states)
        want, want_inverse = np.unique(states, axis=0, return_inverse=True)
        assert unique.tobytes() == want.tobytes()
        assert np.array_equal(inverse, want_inverse.reshape(-1))
        assert np.array_equal(unique[inverse], states)


def reference_probe(probe, times_s):
    """The straightforward way: the state at every time, np.unique over rows, the skin at the touching ones."""
    state = probe.state(times_s)
    out = np.broadcast_to(probe._baseline, (len(state), probe._baseline.size)).copy()
    touching = state[:, 2] > 0
    unique, inverse = np.unique(state[touching], axis=0, return_inverse=True)
    r = probe.skin.pair_resistance_ohm(unique[:, 0], unique[:, 1], unique[:, 2], **probe._skin_kwargs)
    out[touching] = r[inverse.reshape(-1)]
    force = probe.skin.contact_force_n(np.maximum(state[:, 2], 0.0))
    return out, force


@pytest.mark.parametrize("depth_offset_mm, drag_mm", [(0.0, 0.0), (0.17, 0.0), (-0.3, 0.0), (0.0, 0.6)])
def test_the_probe_evaluates_the_skin_only_where_it_may_touch_with_the_same_bits(skin, depth_offset_mm, drag_mm):
    """A vertical press takes x, y once and dedups by depth; a press dragged sideways on the lift takes the
    general path (a row sort); both give the straightforward evaluation's bits."""
    calibration = Calibration(offset_x_mm=100.0, offset_y_mm=100.0, rotation_deg=1.5, surface_z_mm=SURFACE_Z_MM)
    segments = press_segments(drag_mm=drag_mm)
    conditions = PressConditions(dx_mm=0.4, dy_mm=-0.2, depth_offset_mm=depth_offset_mm, resistivity_factor=1.01)
    probe = DryProbe(skin, calibration, lambda t0_s: segments, conditions=lambda press_id: conditions)
    daq_t0 = 7 * 1000.0
    probe.load(7, 0.0, daq_t0, 8.54)
    assert probe._held_xy() == (drag_mm == 0.0)
    slot_times = daq_t0 + np.arange(0.0061, 8.54, 0.0122)
    fsr_times = daq_t0 + np.arange(0.0, 8.54, 0.001)
    want_r, _ = reference_probe(probe, slot_times)
    _, want_force = reference_probe(probe, fsr_times)
    got_r = probe.pair_resistance_ohm(slot_times)
    assert got_r.tobytes() == want_r.tobytes()
    pairs = np.arange(slot_times.size) % 28  # each slot's own pair, as the DAQ asks
    own = probe.slot_resistance_ohm(slot_times, pairs)
    assert own.tobytes() == want_r[np.arange(slot_times.size), pairs].tobytes()
    assert probe.force_n(fsr_times).tobytes() == want_force.tobytes()
    touching = probe.state(slot_times)[:, 2] > 0
    assert 200 < touching.sum() < 400  # the press does reach into the skin, and the lift leaves it
    assert np.all(got_r[~touching] == probe._baseline)
    near = probe.may_touch(fsr_times)
    assert near.size < fsr_times.size and np.all(probe.force_n(np.delete(fsr_times, near)) == 0.0)


def test_a_press_that_stays_above_the_skin_touches_nothing(skin):
    top = (10.0, 10.0, 15.5)
    segments = [Segment(0.0, 1.0, top, (10.0, 10.0, SURFACE_Z_MM + 0.5), 5.0, 100.0, False, 1.0)]
    probe = DryProbe(skin, Calibration(surface_z_mm=SURFACE_Z_MM), lambda t0_s: segments)
    probe.load(0, 0.0, 0.0, 2.0)
    times = np.linspace(0.0, 2.0, 500)
    assert probe.may_touch(times).size == 0
    assert np.all(probe.force_n(times) == 0.0)
    assert probe.pair_resistance_ohm(times).tobytes() == np.tile(skin.baseline_pair_resistance_ohm, (500, 1)).tobytes()


@pytest.mark.parametrize("samples_per_period, n_live, window", [(10.0, 100, 10), (10.0, 37, 5), (12.5, 100, 10)])
def test_rms_sin2_sums_from_the_phase_table_are_the_bits_of_the_full_sum(samples_per_period, n_live, window):
    from neatskin.acquisition.demod import window_counts

    first = 123_456_780 + np.arange(25)[:, None] * 3416 + np.arange(20, 28 * 122, 122)[None, :]
    c = window_counts(n_live, window)
    full = (c**2 * _sine(first[..., None] + np.arange(n_live), samples_per_period) ** 2).sum(axis=-1)
    assert _weighted_sin2_sums(first, samples_per_period, n_live, window).tobytes() == full.tobytes()


def test_residual_dents_per_block_are_pure_in_the_press_id_and_match_the_per_press_sum(tmp_path):
    """Dents and their baselines come from a block of presses fixed by the press id: the same bits whichever press
    a run starts at (resume) and in whatever order the presses are asked for; the sum over the dents matches the
    per-press quadrature to a few ulps (the quadrature's reductions round by batch), the baseline is the per-press
    solve of the same extra factor bit for bit."""
    from test_scene_campaign import make_protocol

    from neatskin.gcode.spec import build_from_spec
    from neatskin.rig.dryrig import dry_scene
    from neatskin.rig.plan import build_plan
    from neatskin.rig.protocol import load_protocol
    from neatskin.sim.dryscene import DENT_BLOCK_PRESSES, press_conditions
    from neatskin.skin.variability import Relaxation

    lines = ("hysteresis_fraction = 0.2", "relaxation_time_s = 60.0", "temperature_drift_k_per_h = 20.0")
    protocol = load_protocol(make_protocol(tmp_path, ("count = 6", "count = 150"), scene_lines=lines))
    skin = SkinModel(protocol.layout, displaced_fluid_fraction=0.5)
    program, _, _ = build_from_spec(
        protocol.press, hold_in_gcode=False, layout=protocol.layout, profile=protocol.printer
    )
    commanded = np.array([(b.x_mm, b.y_mm, protocol.press.press.depth_mm) for b in program.presses])
    n_presses = len(commanded)
    assert n_presses > DENT_BLOCK_PRESSES  # more than one block
    ids = [0, 1, 2, 255, 256, 257, n_presses - 1]
    dry = dry_scene(protocol, build_plan(protocol))
    in_order = {k: press_conditions(dry, skin)(k) for k in ids}
    resumed = press_conditions(dry, skin)  # a resumed run asks for a later block first
    for k in reversed(ids):
        got, want = resumed(k), in_order[k]
        assert (got.extra_factor is None) == (want.extra_factor is None) == (k == 0)
        if k:
            assert got.extra_factor.tobytes() == want.extra_factor.tobytes()
            assert got.baseline_pair_resistance_ohm.tobytes() == want.baseline_pair_resistance_ohm.tobytes()
    relaxation = Relaxation(0.2, 60.0, protocol.scene.press_interval_s or _interval(protocol))
    for k in ids[1:]:
        dents = relaxation.residual_dents(k, commanded)
        per_press = (skin.pinch_factor(dents[:, 0], dents[:, 1], dents[:, 2]) - 1.0).sum(axis=0)
        got = in_order[k]
        np.testing.assert_allclose(got.extra_factor, per_press, rtol=1e-14, atol=1e-17)
        assert np.all(got.extra_factor >= 0) and got.extra_factor.max() > 0.01  # dents near the press, none far
        solved = skin.pair_resistance_ohm(
            0.0, 0.0, 0.0, resistivity_factor=got.resistivity_factor, extra_factor=got.extra_factor[None, :]
        )[0]
        assert solved.tobytes() == got.baseline_pair_resistance_ohm.tobytes()


def _interval(protocol):
    from neatskin.rig.plan import build_plan

    plan = build_plan(protocol)
    return plan.printer_time_s / max(plan.n_presses, 1)


def test_the_daq_reads_the_same_estimates_through_the_slot_source(skin):
    """SimulatedDAQ with slot_resistance_ohm (each slot's own pair only) gives the estimates of the full
    (times, pairs) source bit for bit, on the features path and the waveform path."""
    from neatskin.acquisition.daq.base import DaqConfig
    from neatskin.acquisition.sequence import build_sweep
    from neatskin.acquisition.wiring import load_wiring
    from neatskin.sim.daq import NoiseModel, SimulatedDAQ

    calibration = Calibration(offset_x_mm=100.0, offset_y_mm=100.0, surface_z_mm=SURFACE_Z_MM)
    segments = press_segments()
    probe = DryProbe(skin, calibration, lambda t0_s: segments)
    probe.load(3, 0.0, 3000.0, 8.54)
    sweep = build_sweep(load_wiring(PROTOCOLS / "wiring" / "paper.toml", skin.layout))
    noise = NoiseModel(drift_per_s=1e-4)
    both = [
        SimulatedDAQ(DaqConfig(amplitude_a=5e-4), probe.pair_resistance_ohm, probe.force_n, noise=noise),
        SimulatedDAQ(
            DaqConfig(amplitude_a=5e-4),
            probe.pair_resistance_ohm,
            probe.force_n,
            noise=noise,
            slot_resistance_ohm=probe.slot_resistance_ohm,
        ),
    ]
    features = [d.estimate_sweep(sweep, np.random.default_rng(1), 3000.0, "rms", 10, n_sweeps=25) for d in both]
    assert features[0].resistance_ohm.tobytes() == features[1].resistance_ohm.tobytes()
    assert features[0].uncertainty_ohm.tobytes() == features[1].uncertainty_ohm.tobytes()
    touched = features[0].resistance_ohm.std(axis=0) > 50.0  # the press moves the pairs it reaches
    assert touched.any() and not touched.all()
    waves = [d.acquire(sweep, 2, rng=np.random.default_rng(2), start_time_s=3003.0) for d in both]
    assert waves[0].samples.tobytes() == waves[1].samples.tobytes()

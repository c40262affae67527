"""The dry run's paper-like scene on the finite-element pinch: a press that cuts an electrode off gives the row a
real rig would record (R and dR +inf, open circuit and clipping flagged), the baselines keep it with its dR
saturated; and a calibration error of the scene is not cancelled by the recorder (the skin feels where the probe
really is)."""

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.acquisition.estimates import PairFlag
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring
from neatskin.baselines.dataset import SATURATION_FACTOR, load_baseline_data, saturate
from neatskin.gcode.calibration import Calibration
from neatskin.layout import load_layout
from neatskin.sim.daq import NoiseModel, SimulatedDAQ
from neatskin.sim.dryprobe import DryProbe, skin_frame
from neatskin.sim.dryscene import DryScene, dry_skin, frame_error
from neatskin.sim.motion import Segment
from neatskin.sim.scene import Scene
from neatskin.skin.model import SkinModel

SURFACE_Z_MM = 5.5


@pytest.fixture(scope="module")
def layout():
    return load_layout(PROTOCOLS / "skins" / "paper.toml")


def dry(layout, scene):
    return DryScene(scene, layout, Calibration(), DaqConfig(), 1, 2.75, "rms", 10, 7.78)


def test_the_paper_like_preset_uses_the_fe_kernel_and_ideal_the_parametric_pinch(layout):
    assert Scene(preset="paper-like").deformation == "fe-kernel"
    assert Scene().deformation == "parametric"
    assert Scene(preset="paper-like", deformation="parametric").deformation == "parametric"
    assert dry_skin(dry(layout, Scene(preset="paper-like"))).deformation == "fe-kernel"
    assert dry_skin(dry(layout, Scene())).deformation == "parametric"


def test_a_press_on_electrode_2_cuts_its_pairs_and_the_daq_flags_open_circuit(layout):
    """Electrode 2 is the corner junction (30, 0): two channels leave it, and a 3.5 mm press on it shuts both
    (the FE kernel shuts a channel within ~3 mm of the probe axis at that depth). Its 7 pairs read R_eq = inf,
    every other pair stays finite; the simulated galvanostat hits its compliance, the current collapses and
    the demodulator flags open circuit (R = inf, never a division by zero) and clipping."""
    skin = dry_skin(dry(layout, Scene(preset="paper-like", noise=False)))
    r = skin.pair_resistance_ohm(30.0, 0.0, 3.5)[0]
    cut = np.array([2 in (p.i, p.j) for p in layout.pairs])
    assert np.all(np.isinf(r[cut])) and np.all(np.isfinite(r[~cut]))
    parametric = SkinModel(layout).pair_resistance_ohm(30.0, 0.0, 3.5)[0]
    assert np.all(np.isfinite(parametric))  # the old pinch never shut a channel: the negative control
    sweep = build_sweep(load_wiring(PROTOCOLS / "wiring" / "paper.toml", layout))
    daq = SimulatedDAQ(DaqConfig(), lambda t: np.tile(r, (len(np.atleast_1d(t)), 1)), noise=NoiseModel.none())
    est = daq.estimate_sweep(sweep, np.random.default_rng(0), method="rms")
    flags = est.flags.reshape(-1, len(layout.pairs))[0]
    assert np.all(flags[cut] & PairFlag.OPEN_CIRCUIT) and not np.any(flags[~cut] & PairFlag.OPEN_CIRCUIT)
    assert np.all(np.isinf(est.resistance_ohm.reshape(-1, len(layout.pairs))[0][cut]))


def test_saturate_puts_a_cut_pair_beyond_every_change_its_column_measured():
    X = np.array([[1.0, -2.0, 0.5], [np.inf, 4.0, 0.25], [3.0, np.inf, np.inf]])
    out, value, n = saturate(X)
    assert n == 2
    assert value.tolist() == [SATURATION_FACTOR * 3.0, SATURATION_FACTOR * 4.0, SATURATION_FACTOR * 0.5]
    assert out.tolist() == [[1.0, -2.0, 0.5], [6.0, 4.0, 0.25], [3.0, 8.0, 1.0]]


def test_the_baselines_keep_a_cut_press_saturated_and_drop_other_flagged_ones(tmp_path, layout):
    from test_baselines_report import small_table, write_dataset

    df = small_table()
    df.at[3, "dR_ohm_1_2"] = np.inf  # electrode 1 cut off: the row as the rig writes it
    df.at[3, "flags"] = ["open_circuit:1-2", "clipped:1-2"]
    df.at[5, "flags"] = ["fsr_missed"]  # not a cut: dropped as before
    folder = write_dataset(tmp_path / "ds", df)
    data = load_baseline_data(folder)
    assert data.n_saturated == 1 and data.n_flagged_dropped == 1 and len(data.y) == len(df) - 1
    k = data.pair_columns.index("dR_ohm_1_2")
    finite = pd.to_numeric(df["dR_ohm_1_2"]).drop(index=[3, 5])
    want = SATURATION_FACTOR * float(np.abs(pd.to_numeric(df["dR_ohm_1_2"]).drop(index=3)).max())
    assert data.saturation_ohm[k] == want
    assert data.X[3, k] == want and np.all(np.isfinite(data.X))
    np.testing.assert_array_equal(np.delete(data.X[:, k], 3), finite.to_numpy())
    dropped = load_baseline_data(folder, flagged="drop")
    assert dropped.n_flagged_dropped == 2 and dropped.n_saturated == 0


def press_segments(x, y):
    top, contact, deep = (x, y, 15.5), (x, y, SURFACE_Z_MM), (x, y, 2.0)
    return [
        Segment(0.0, 2.05, top, contact, 5.0, 100.0, False, 2.05),
        Segment(2.05, 3.82, contact, deep, 2.0, 100.0, False, 1.77),
    ]


@pytest.mark.parametrize("error", [(1.5, -0.75, 0.0), (0.0, 0.0, 90.0), (2.0, 1.0, 3.0)])
def test_a_press_commanded_at_x_lands_at_x_plus_the_offset_in_the_skins_frame(layout, error):
    """The G-code converts the commanded sensor point to printer coordinates with the calibration; the recorder
    converts the printer's position back with the same calibration (which alone gives the commanded point:
    the negative control) and then into the skin's real frame."""
    calibration = Calibration(offset_x_mm=100.0, offset_y_mm=90.0, rotation_deg=1.5, surface_z_mm=SURFACE_Z_MM)
    commanded = (12.0, 7.0)
    px, py = calibration.to_printer(*commanded)
    segments = press_segments(float(px), float(py))
    skin = SkinModel(layout)
    times = np.array([3.82])
    plain = DryProbe(skin, calibration, lambda t0: segments)
    plain.load(0, 0.0, 0.0, 4.0)
    np.testing.assert_allclose(plain.state(times)[0, :2], commanded, atol=1e-6)
    moved = DryProbe(skin, calibration, lambda t0: segments, frame_error=error)
    moved.load(0, 0.0, 0.0, 4.0)
    dx, dy, rot = error
    c, s = np.cos(np.radians(rot)), np.sin(np.radians(rot))
    want = (c * 12.0 - s * 7.0 + dx, s * 12.0 + c * 7.0 + dy)
    np.testing.assert_allclose(moved.state(times)[0, :2], want, atol=1e-6)
    assert skin_frame(12.0, 7.0, error) == pytest.approx(want)
    if error == (0.0, 0.0, 90.0):
        np.testing.assert_allclose(moved.state(times)[0, :2], (-7.0, 12.0), atol=1e-6)  # exact quarter turn


def test_the_scenes_frame_error_reaches_the_probe(layout):
    assert frame_error(Scene()) is None
    assert frame_error(Scene(frame_offset_x_mm=1.0, frame_rotation_deg=-2.0)) == (1.0, 0.0, -2.0)


def test_the_features_path_reads_a_cut_pair_as_the_waveform_path_does(layout):
    """A cut pair no longer sends the whole sweep to the waveform path: the features path gives it the reading
    the waveform path gives (R and uncertainty inf, OPEN_CIRCUIT | CLIPPED) with the paper's DAQ and noise, and
    the other pairs their analytic estimates (no DC flag, finite). Without clipping (noise.clip off) it defers."""
    from neatskin.rig.assembly import daq_config
    from neatskin.rig.protocol import load_protocol

    cfg = daq_config(load_protocol(PROTOCOLS / "paper.toml"))
    r = SkinModel(layout).baseline_pair_resistance_ohm.copy()
    cut = np.array([1 in (p.i, p.j) for p in layout.pairs])
    r[cut] = np.inf
    sweep = build_sweep(load_wiring(PROTOCOLS / "wiring" / "paper.toml", layout))
    daq = SimulatedDAQ(cfg, lambda t: np.tile(r, (len(np.atleast_1d(t)), 1)), noise=NoiseModel())
    assert daq._surely_open_and_clipped()
    features = daq.estimate_sweep(sweep, np.random.default_rng(1), method="rms", n_sweeps=2)
    from neatskin.acquisition.demod import demodulate

    waveforms = demodulate(daq.acquire(sweep, 2, rng=np.random.default_rng(1)), sweep, method="rms", window=10)
    np.testing.assert_array_equal(features.flags[:, cut], waveforms.flags[:, cut])
    assert np.all(features.flags[:, cut] == PairFlag.OPEN_CIRCUIT | PairFlag.CLIPPED)
    assert np.all(np.isinf(features.resistance_ohm[:, cut])) and np.all(np.isinf(waveforms.resistance_ohm[:, cut]))
    np.testing.assert_allclose(features.resistance_ohm[:, ~cut], waveforms.resistance_ohm[:, ~cut], rtol=2e-3)
    assert not np.any(features.flags[:, ~cut])
    unclipped = SimulatedDAQ(cfg, daq.pair_resistance_ohm, noise=NoiseModel(clip=False))
    assert not unclipped._surely_open_and_clipped()

"""physical_limit.parquet: the electronics-only bound and the bound with the scene's nuisances (depth, drift,
placement), on a smoke dry run and on the paper skin with the paper-like scene's priors."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import PROTOCOLS, shared_folder

from neatskin.baselines.crb import cramer_rao_bound_mm
from neatskin.rig.physlimit import METADATA_KEY, NuisancePriors, physical_limit_frame
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.sim.scene import PAPER_LIKE, Scene
from neatskin.skin.bound import feature_jacobian
from neatskin.skin.model import SkinModel


# this module's, made once per session (conftest.shared_folder; module scope remade it whenever the suite's order
# came back to the module, session scope once per worker)
@pytest.fixture(scope="session")
def smoke_limit(tmp_path_factory):
    protocol = load_protocol(PROTOCOLS / "smoke.toml")

    def make(root):
        run_campaign(protocol, root / "campaign", dry_run=True, progress=False, report=False)

    folder = shared_folder(tmp_path_factory, "smoke-limit", make) / "campaign"
    return protocol, pq.read_table(folder / "physical_limit.parquet")


def test_the_smoke_run_writes_both_bounds_with_what_was_assumed(smoke_limit):
    protocol, table = smoke_limit
    assert table.column_names[:5] == ["position_id", "x_mm", "y_mm", "crb_mm", "crb_nuisance_mm"]
    assert table.column_names[5:] == [
        "landing_bound_mm",
        "landing_bound_known_skin_mm",
        "label_floor_new_positions_mean_mm",
        "label_floor_new_positions_rms_mm",
        "label_floor_by_row_mean_mm",
        "label_floor_by_row_rms_mm",
    ]
    limit = table.to_pandas()
    assert sorted(limit.position_id) == list(range(6))
    assert np.isfinite(limit.crb_mm).all() and (limit.crb_mm > 0).all()
    meta = json.loads(table.schema.metadata[METADATA_KEY])
    assert meta["priors"] == {"depth_std_mm": 0.0, "drift_std": 0.0, "placement_std_mm": 0.0}
    assert "assumed" in meta["basis"] and meta["depth_mm"] == protocol.press.press.depth_mm
    # the smoke scene is ideal: no placement error, so no label-noise floor; no fabrication spread
    assert (limit.filter(like="label_floor_").to_numpy() == 0).all()
    np.testing.assert_array_equal(limit.landing_bound_mm.to_numpy(), limit.landing_bound_known_skin_mm.to_numpy())


def test_the_ideal_scene_has_no_nuisance_so_the_bounds_are_equal(smoke_limit):
    protocol, table = smoke_limit
    assert protocol.scene.preset == "ideal"
    limit = table.to_pandas()
    np.testing.assert_array_equal(limit.crb_nuisance_mm.to_numpy(), limit.crb_mm.to_numpy())


def test_the_electronics_bound_is_the_baselines_bound(paper_layout):
    """The batched bound equals neatskin.baselines.crb per position (the writer's former per-position loop)."""
    skin = SkinModel(paper_layout)
    x, y = np.array([5.0, 15.0, 22.5]), np.array([5.0, 15.0, 7.5])
    jac = feature_jacobian(skin, x, y, np.full(3, 3.5))
    std = np.random.default_rng(1).uniform(0.05, 0.2, (3, jac.shape[1]))
    frame = physical_limit_frame([0, 1, 2], x, y, jac, std, NuisancePriors(0.0, 0.0, 0.0))
    expected = [cramer_rao_bound_mm(jac[k : k + 1, :, :2], noise_std=std[k])[0] for k in range(3)]
    np.testing.assert_allclose(frame.crb_mm.to_numpy(), expected, rtol=1e-9)


def test_paper_like_nuisances_never_lower_the_bound(paper_layout):
    skin = SkinModel(paper_layout)
    gx, gy = np.meshgrid(np.arange(1.0, 30.0, 2.0), np.arange(1.0, 30.0, 2.0))
    x, y = gx.ravel(), gy.ravel()
    jac = feature_jacobian(skin, x, y, np.full(x.size, 3.5))
    std = np.full(jac.shape[:2], 0.1 * np.sqrt(2.0))
    scene = Scene(fidelity="deformation", signal="features", noise=True, **PAPER_LIKE)
    priors = NuisancePriors.from_scene(scene, 6.05 * 3600.0)
    assert priors.depth_std_mm == PAPER_LIKE["depth_jitter_mm"]
    assert priors.placement_std_mm == PAPER_LIKE["placement_error_mm"]
    frame = physical_limit_frame(np.arange(x.size), x, y, jac, std, priors)
    electronics, nuisance = frame.crb_mm.to_numpy(), frame.crb_nuisance_mm.to_numpy()
    assert np.all(nuisance >= electronics)
    assert np.all(
        nuisance >= np.sqrt(2.0) * PAPER_LIKE["placement_error_mm"]
    )  # the landing point's own spread, whatever the pairs see
    depth_drift = physical_limit_frame(
        np.arange(x.size), x, y, jac, std, NuisancePriors(priors.depth_std_mm, priors.drift_std, 0.0)
    ).crb_nuisance_mm.to_numpy()
    assert np.all(depth_drift >= electronics * (1 - 1e-12)) and np.any(depth_drift > 2 * electronics)


def test_the_drift_prior_is_the_ramps_spread_in_log_rho():
    scene = Scene(
        fidelity="deformation",
        signal="features",
        noise=True,
        placement_error_mm=0.0,
        temperature_drift_k_per_h=0.5,
        evaporation_fraction_per_h=0.0,
    )
    priors = NuisancePriors.from_scene(scene, 2 * 3600.0, tempco_per_k=-0.02)
    assert priors.drift_std == pytest.approx(-np.log(1 - 0.02 * 0.5 * 2) / np.sqrt(12), rel=1e-12)
    assert NuisancePriors.from_scene(scene, 0.0).drift_std == 0.0


def test_a_scene_without_noise_has_a_zero_electronics_bound_and_a_report(tmp_path):
    """`noise = false`: no estimator noise, so an identifiable position is measured exactly (bound 0, not a crash)."""
    import shutil

    import pandas as pd

    root = tmp_path / "protocols"
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    assert "\nnoise = true" in text
    (root / "quiet.toml").write_text(text.replace("\nnoise = true", "\nnoise = false"))
    result = run_campaign(load_protocol(root / "quiet.toml"), tmp_path / "run", progress=False, report=True)
    limit = pd.read_parquet(tmp_path / "run" / "physical_limit.parquet")
    assert result.completed == 12 and len(limit) == 6
    assert (limit["crb_mm"] == 0.0).all() and (limit["crb_nuisance_mm"] == 0.0).all()  # the smoke scene is ideal
    assert "Cramér-Rao" in (tmp_path / "run" / "report.md").read_text()


def test_typical_phases_are_the_plans_phase_times():
    from neatskin.gcode.motion import phase_durations_s
    from neatskin.rig.physlimitnoise import typical_phases_s
    from neatskin.rig.plan import build_plan

    protocol = load_protocol(PROTOCOLS / "smoke.toml")
    plan = build_plan(protocol)
    durations = phase_durations_s(plan.program, protocol.printer)
    np.testing.assert_array_equal(plan.phase_s, durations)
    np.testing.assert_array_equal(typical_phases_s(plan), np.median(durations, axis=0))


def test_a_pair_cut_off_at_a_position_leaves_the_others_their_information(tmp_path):
    """The FE skin at the paper's depth cuts pairs off under some presses: such a pair's noise is not finite there.
    It drops out of that position's bound, and every other position keeps a finite, positive bound (a NaN once sent
    every position to the noise-free branch: a bound of 0 everywhere)."""
    import numpy as np
    import pyarrow.parquet as pq

    from neatskin.rig.dryrig import dry_scene
    from neatskin.rig.physlimit import write_physical_limit
    from neatskin.rig.plan import build_plan
    from neatskin.rig.protocol import load_protocol
    from neatskin.sim.daq import NoiseModel, SimulatedDAQ
    from neatskin.sim.dryscene import dry_skin, interface_noise

    protocol = load_protocol(str(PROTOCOLS / "paper.toml"))
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    unpressed = np.asarray(skin.baseline_pair_resistance_ohm, float)
    daq = SimulatedDAQ(  # the dry run's DAQ settings and noise; physlimit sets each state itself
        dry.daq,
        lambda t: np.broadcast_to(unpressed, (len(t), unpressed.size)),
        noise=interface_noise(NoiseModel(), dry.scene),
    )
    frame = pq.read_table(write_physical_limit(tmp_path, protocol, plan, skin, daq)).to_pandas()
    crb = frame["crb_mm"].to_numpy()
    assert np.all(crb > 0)  # never the noise-free branch's 0
    # around a junction at 3.5 mm every channel the probe reaches is shut and the others are beyond the pinch's
    # reach: moving within that spot changes no graded reading, so the position is unobservable from graded values
    # (inf; the cut pattern alone tells it): 23 of the paper's 100 positions. Along a channel's middle the far-field
    # pinch of the perpendicular channels' ends (R x ~1.007 at 7.5 mm) still changes, so the bound is finite there
    assert 0.4 < np.isfinite(crb).mean() < 1.0
    finite = np.isfinite(crb)
    assert np.all(frame["crb_nuisance_mm"].to_numpy()[finite] >= crb[finite])  # nuisances never help


def test_the_limit_computed_while_the_worker_presses_is_the_one_computed_at_the_end(tmp_path, monkeypatch):
    """With a skin worker the dry rig computes the physical limit in a thread while the campaign presses (it
    depends on no press); the file is the one the run without a worker computes at the end, bit for bit."""
    import dataclasses

    import neatskin.rig.dryrig as dryrig

    smoke = load_protocol(PROTOCOLS / "smoke.toml")
    protocol = dataclasses.replace(smoke, scene=dataclasses.replace(smoke.scene, signal="features"))
    started = []
    monkeypatch.setattr(dryrig.Ahead, "__init__", _counted(dryrig.Ahead.__init__, started))
    tables = {}
    for mode in ("off", "on"):
        monkeypatch.setenv("NEATSKIN_SKIN_WORKER", mode)
        run_campaign(protocol, tmp_path / mode, dry_run=True, progress=False, report=False)
        tables[mode] = pq.read_table(tmp_path / mode / "physical_limit.parquet")
    assert len(started) == 1  # only the run with the worker computed it ahead
    assert tables["on"].equals(tables["off"])
    assert tables["on"].schema.metadata == tables["off"].schema.metadata


def _counted(init, calls):
    def counted(self, *args, **kwargs):
        calls.append(1)
        init(self, *args, **kwargs)

    return counted


def test_a_computation_ahead_gives_its_value_or_raises_its_error_when_asked():
    from neatskin.rig.dryrig import Ahead

    assert Ahead(lambda: 6 * 7).result() == 42

    def fails() -> None:
        raise ValueError("no skin")

    ahead = Ahead(fails)
    with pytest.raises(ValueError, match="no skin"):
        ahead.result()

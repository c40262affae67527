"""The simulated-campaign engine: a protocol's presses drawn straight from its skin model and its scene's noise, with
no printer, pty or DAQ waveforms, so a campaign of thousands of presses takes a fraction of a second.

What a press gets (each from its own random stream keyed by (seed, stream)): the position strategy's positions
for the campaign seed, pressed in position order; placement error N(0, s^2) per axis about the commanded
position (the label); depth jitter; the fluid drift of the press's campaign time (press index x the scene's
press interval); the skin's fabrication spread (fixed by the protocol's seed: one skin, many campaigns); white
measurement noise per pair with the std of the dry run's DAQ estimator (unpressed state, the sweeps a press
averages; `rig.physlimit`). Left out (assumed small): silicone relaxation dents, the FSR label and its misses,
mux transients. Rig time comes from the G-code of the same positions (`build_plan`), not from the engine.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass

import numpy as np

STREAMS = {"placement": 1, "depth": 2, "noise": 3}


@dataclass(frozen=True)
class CampaignSize:
    """One campaign design: positions x repeats at one depth."""

    positions: int
    repeats: int
    depth_mm: float

    @property
    def presses(self) -> int:
        return self.positions * self.repeats


@dataclass(frozen=True)
class Presses:
    """A simulated campaign: features (presses, pairs) in ohm, commanded (labels) and landed positions, groups."""

    features: np.ndarray
    commanded_mm: np.ndarray
    landed_mm: np.ndarray
    groups: np.ndarray


def _build_plan(protocol):
    """The runner's plan builder, wherever it lives (rig/plan.py or rig/runner.py)."""
    for name in ("neatskin.rig.plan", "neatskin.rig.runner"):
        try:
            return importlib.import_module(name).build_plan(protocol)
        except (ImportError, AttributeError):
            continue
    raise ImportError("no build_plan in neatskin.rig.plan or neatskin.rig.runner")  # pragma: no cover


def with_size(protocol, size: CampaignSize, seed: int | None = None):
    """The protocol with the size's positions, repeats and depth (and the positions' seed)."""
    press = protocol.press
    positions = dataclasses.replace(
        press.positions, count=int(size.positions), seed=press.positions.seed if seed is None else int(seed)
    )
    spec = dataclasses.replace(
        press,
        positions=positions,
        press=dataclasses.replace(press.press, repeats=int(size.repeats), depth_mm=float(size.depth_mm)),
    )
    return dataclasses.replace(protocol, press=spec)


def rig_hours(protocol, size: CampaignSize) -> float:
    """The G-code's rig time for the size (travel, descent, press, lift, hold), in hours."""
    return float(_build_plan(with_size(protocol, size)).printer_time_s) / 3600.0


def press_interval_s(protocol) -> float:
    """Campaign time between presses for the drift: the scene's, else the protocol's G-code time per press."""
    interval = float(getattr(protocol.scene, "press_interval_s", 0.0))
    if interval:
        return interval
    plan = _build_plan(protocol)
    return float(plan.printer_time_s) / max(plan.n_presses, 1)


def pair_noise_std_ohm(protocol) -> np.ndarray:
    """Std of one press's dR per pair (pairs,): the dry run's DAQ estimator noise at the unpressed skin, averaged
    over the sweeps a press records (as `rig.physlimit` computes it per position)."""
    from types import SimpleNamespace

    from neatskin.rig.physlimit import _dr_noise_std_ohm

    assembly = importlib.import_module("neatskin.rig.assembly")
    from neatskin.sim.daq import NoiseModel

    scene = protocol.scene
    noise = assembly.interface_noise(NoiseModel() if scene.noise else NoiseModel.none(), scene)
    skin = assembly.dry_skin(protocol)
    rig = SimpleNamespace(skin=skin, daq=SimpleNamespace(config=assembly.daq_config(protocol), noise=noise))
    x0, y0, x1, y1 = protocol.layout.bounds_mm
    x, y = np.array([(x0 + x1) / 2]), np.array([(y0 + y1) / 2])
    std = _dr_noise_std_ohm(protocol, _build_plan(protocol), rig, x, y, np.array([protocol.press.press.depth_mm]))
    return np.asarray(std, float).reshape(-1)


def skin_of(protocol, pinch_scale: float = 1.0):
    """The dry run's skin of the protocol; pinch_scale multiplies its pinch (a deliberately wrong physics)."""
    skin = importlib.import_module("neatskin.rig.assembly").dry_skin(protocol)
    if pinch_scale == 1.0:
        return skin
    pinch = skin.pinch
    field = next((f for f in ("pinch_gain", "max_fraction", "amplitude") if hasattr(pinch, f)), None)
    if field is None:  # a pinch kernel without a gain: say so rather than scale something else
        raise TypeError(f"{type(pinch).__name__} has no pinch gain to scale (pinch_gain, max_fraction, amplitude)")
    return dataclasses.replace(skin, pinch=dataclasses.replace(pinch, **{field: getattr(pinch, field) * pinch_scale}))


def simulate_presses(
    protocol,
    commanded_xy_mm: np.ndarray,
    repeats: int,
    depth_mm: float,
    seed: int,
    noise_std_ohm: np.ndarray,
    *,
    skin=None,
    interval_s: float | None = None,
    first_press: int = 0,
) -> Presses:
    """Every position pressed `repeats` times in a row (position order), from press index `first_press` on."""
    from neatskin.skin.variability import drift_resistivity_factor

    scene = protocol.scene
    skin = skin_of(protocol) if skin is None else skin
    commanded = np.repeat(np.asarray(commanded_xy_mm, float).reshape(-1, 2), repeats, axis=0)
    groups = np.repeat(np.arange(len(commanded_xy_mm)), repeats)
    n = len(commanded)
    sigma = float(scene.placement_error_mm)
    landed = commanded + sigma * np.random.default_rng([seed, STREAMS["placement"]]).standard_normal((n, 2))
    jitter = float(getattr(scene, "depth_jitter_mm", 0.0))
    depth = depth_mm + jitter * np.random.default_rng([seed, STREAMS["depth"]]).standard_normal(n)
    interval = press_interval_s(protocol) if interval_s is None else interval_s
    t_s = (first_press + np.arange(n)) * interval
    drift = np.asarray(
        drift_resistivity_factor(
            t_s,
            float(getattr(scene, "temperature_drift_k_per_h", 0.0)),
            float(getattr(scene, "evaporation_fraction_per_h", 0.0)),
            float(getattr(skin, "resistivity_tempco_per_k", -0.02)),
        ),
        float,
    ) * np.ones(n)
    pressed = np.asarray(skin.pair_resistance_ohm(landed[:, 0], landed[:, 1], depth, resistivity_factor=drift), float)
    base = np.asarray(skin.baseline_pair_resistance_ohm, float)[None, :] * drift[:, None]
    noise = np.random.default_rng([seed, STREAMS["noise"]]).standard_normal(pressed.shape) * noise_std_ohm[None, :]
    features = pressed - base + noise
    features = np.where(np.isfinite(features), features, 0.0)  # a pair cut off reads as no change (flagged in a run)
    return Presses(features, commanded, landed, groups)


def strategy_positions(protocol, count: int, seed: int) -> np.ndarray:
    """`count` positions of the protocol's strategy for the seed, (count, 2) mm."""
    from neatskin.gcode.positions import generate_positions

    spec = dataclasses.replace(protocol.press.positions, count=int(count), seed=int(seed))
    return generate_positions(protocol.layout, spec).xy_mm


def fit_and_score(model_name: str, train: Presses, test: Presses, random_state: int) -> float:
    """Mean Euclidean error (mm) against the test's commanded positions of the named baseline fitted on train."""
    from neatskin.baselines.models import make_models

    model = make_models(
        [model_name],
        random_state=random_state,
        n_features=train.features.shape[1],
        n_rows=len(train.features),
        lm_restarts=1,
    )[model_name]
    model.fit(train.features, train.commanded_mm)
    predicted = np.asarray(model.predict(test.features), float)
    return float(np.mean(np.linalg.norm(predicted - test.commanded_mm, axis=1)))

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
from dataclasses import dataclass
from typing import Any

import numpy as np

from neatskin.gcode.positions import generate_positions
from neatskin.rig.assembly import daq_config
from neatskin.rig.dryrig import dry_scene
from neatskin.rig.physlimitnoise import dr_noise_std_ohm
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.sim.daq import NoiseModel, SimulatedDAQ
from neatskin.sim.dryscene import dry_skin, interface_noise
from neatskin.skin.model import SkinModel
from neatskin.skin.variability import drift_resistivity_factor

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


def with_size(protocol: CampaignProtocol, size: CampaignSize, seed: int | None = None) -> CampaignProtocol:
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


def rig_hours(protocol: CampaignProtocol, size: CampaignSize) -> float:
    """The G-code's rig time for the size (travel, descent, press, lift, hold), in hours."""
    return float(build_plan(with_size(protocol, size)).printer_time_s) / 3600.0


def press_interval_s(protocol: CampaignProtocol) -> float:
    """Campaign time between presses for the drift: the scene's, else the protocol's G-code time per press."""
    return float(getattr(protocol.scene, "press_interval_s", 0.0)) or build_plan(protocol).press_interval_s


def pair_noise_std_ohm(protocol: CampaignProtocol) -> np.ndarray:
    """Std of one press's dR per pair (pairs,): the dry run's DAQ estimator noise, the unpressed skin's over the
    baseline estimates a press averages and a press at the layout's centre over the pressed ones, counted per pair
    as the recorder's press values select them (`rig.physlimitnoise.dr_noise_std_ohm`, which `rig.physlimit` uses
    per position), with the dry run's skin, DAQ settings and interface noise (neatskin.sim.dryscene)."""
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    noise = interface_noise(NoiseModel() if dry.scene.noise else NoiseModel.none(), dry.scene)
    unpressed = np.asarray(skin.baseline_pair_resistance_ohm, float)

    def at_rest(t: np.ndarray) -> np.ndarray:  # physlimit reads the DAQ's config and noise, and sets each state
        return np.broadcast_to(unpressed, (len(t), unpressed.size))

    daq = SimulatedDAQ(dry.daq, at_rest, noise=noise)
    x0, y0, x1, y1 = protocol.layout.bounds_mm
    x, y = np.array([(x0 + x1) / 2]), np.array([(y0 + y1) / 2])
    std = dr_noise_std_ohm(protocol, plan, skin, daq, x, y, np.array([protocol.press.press.depth_mm]))
    return np.asarray(std, float).reshape(-1)


def skin_of(protocol: CampaignProtocol, pinch_scale: float = 1.0) -> SkinModel:
    """The dry run's skin of the protocol; pinch_scale multiplies its pinch (a deliberately wrong physics)."""
    skin = dry_skin(dry_scene(protocol, build_plan(protocol)))
    return skin if pinch_scale == 1.0 else scale_pinch(skin, pinch_scale)


def scale_pinch(skin: SkinModel, factor: float) -> SkinModel:
    """The skin with its pinch scaled by `factor` >= 0: a finite-element kernel's pinch 1 - A/A0 (clipped to
    [0, 1], `PinchKernel.scaled`) when the skin presses through one, else the parametric pinch gain."""
    if not (np.isfinite(factor) and factor >= 0):
        raise ValueError(f"a pinch scale must be a number >= 0, got {factor!r}")
    if skin.kernel is not None and skin.fidelity == "deformation":  # the kernel decides the pinch (SkinModel)
        return dataclasses.replace(skin, kernel=skin.kernel.scaled(factor))
    return dataclasses.replace(skin, pinch=dataclasses.replace(skin.pinch, pinch_gain=skin.pinch.pinch_gain * factor))


@dataclass(frozen=True)
class PressedSkin:
    """Presses drawn through the skin before the DAQ: pair R_eq (presses, pairs) in ohm, +inf for a pair cut off,
    with the fluid drift factor per press, the commanded and landed positions and the groups."""

    resistance_ohm: np.ndarray
    drift: np.ndarray
    commanded_mm: np.ndarray
    landed_mm: np.ndarray
    groups: np.ndarray


def pressed_skin(
    protocol: CampaignProtocol,
    commanded_xy_mm: np.ndarray,
    repeats: int,
    depth_mm: float,
    seed: int,
    *,
    skin: SkinModel | None = None,
    interval_s: float | None = None,
    first_press: int = 0,
) -> PressedSkin:
    """Every position pressed `repeats` times in a row (position order), from press index `first_press` on,
    through the skin with the scene's placement error, depth jitter and drift: what the DAQ is given."""
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
    return PressedSkin(pressed, drift, commanded, landed, groups)


def simulate_presses(
    protocol: CampaignProtocol,
    commanded_xy_mm: np.ndarray,
    repeats: int,
    depth_mm: float,
    seed: int,
    noise_std_ohm: np.ndarray,
    *,
    skin: SkinModel | None = None,
    interval_s: float | None = None,
    first_press: int = 0,
) -> Presses:
    """Every position pressed `repeats` times in a row (position order), from press index `first_press` on."""
    skin = skin_of(protocol) if skin is None else skin
    drawn = pressed_skin(
        protocol, commanded_xy_mm, repeats, depth_mm, seed, skin=skin, interval_s=interval_s, first_press=first_press
    )
    # beyond the compliance, the AI's reach or the mux rails (amplitude x (R + 2 R_on + mismatch) past a rail: the
    # switch clamps) the rig reads no value: it flags the pair (clipped; open circuit too for a cut one) and the
    # row records +inf, as a cut pair's (acquisition.pressvalues): a channel nearly pinched shut gives a huge but
    # finite R_eq that no rig would record
    readable_ohm = daq_config(protocol).readable_ohm
    pressed = np.where(drawn.resistance_ohm >= readable_ohm, np.inf, drawn.resistance_ohm)
    base = np.asarray(skin.baseline_pair_resistance_ohm, float)[None, :] * drawn.drift[:, None]
    noise = np.random.default_rng([seed, STREAMS["noise"]]).standard_normal(pressed.shape) * noise_std_ohm[None, :]
    features = pressed - base + noise
    # a pair cut off (a channel pinched shut) reads as the baselines read a recorded one: its column's saturation
    # value (baselines.dataset.saturate, here over this call's presses), never as no change
    from neatskin.baselines.dataset import saturate  # here: pressed_skin's callers (the rails check) need no baselines

    features = saturate(features)[0]
    return Presses(features, drawn.commanded_mm, drawn.landed_mm, drawn.groups)


def strategy_positions(protocol: CampaignProtocol, count: int, seed: int) -> np.ndarray:
    """`count` positions of the protocol's strategy for the seed, (count, 2) mm."""
    spec = dataclasses.replace(protocol.press.positions, count=int(count), seed=int(seed))
    return generate_positions(protocol.layout, spec).xy_mm


def fitted_model(model_name: str, train: Presses, random_state: int) -> Any:
    """The named baseline fitted on train's features against its commanded positions."""
    from neatskin.baselines.models import make_models  # scikit-learn: not for pressed_skin's callers

    model = make_models(
        [model_name],
        random_state=random_state,
        n_features=train.features.shape[1],
        n_rows=len(train.features),
        lm_restarts=1,
    )[model_name]
    model.fit(train.features, train.commanded_mm)
    return model


def fit_and_score(model_name: str, train: Presses, test: Presses, random_state: int) -> float:
    """Mean Euclidean error (mm) against the test's commanded positions of the named baseline fitted on train."""
    predicted = np.asarray(fitted_model(model_name, train, random_state).predict(test.features), float)
    return float(np.mean(np.linalg.norm(predicted - test.commanded_mm, axis=1)))

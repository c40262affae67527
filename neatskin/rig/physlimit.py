"""The physical limit of a dry run: per position, the floors on the position error that the simulated skin, its
noise and the labels allow (physical_limit.parquet, beside the presses).

What each column measures (neatskin.baselines.floors has the mathematics):
- `landing_bound_mm`, the landing-point bound: the Cramér-Rao bound on where the press landed, from its 28 dR, with
  the electronics noise and the scene's depth jitter, fluid drift and fabrication spread (log channel heights) as
  nuisances. It is what the skin and the electronics allow; it knows nothing of the labels.
- `label_floor_new_positions_{mean,rms}_mm` and `label_floor_by_row_{mean,rms}_mm`, the label-noise floor: the Bayes
  error against the commanded positions the labels hold, under the scene's placement error, with the prior over
  commanded positions of each split (the position strategy for new positions, the campaign's positions for a split
  by row). With no placement error they are 0.
- `landing_bound_known_skin_mm`: the landing-point bound with the fabrication known (a model trained on this skin
  has seen its channels); fabrication as a per-press nuisance is the bound for a model of another skin.

Two bounds per position, both from `neatskin.skin.bound` with the same per-pair noise std:
`crb_mm` with the electronics noise only (depth, drift and landing point known), and
`crb_nuisance_mm` with the scene's press depth jitter, fluid drift and placement error as nuisance
parameters (their priors, and what was assumed to get them, are in the parquet's schema metadata
under `neatskin.physical_limit`). With no nuisance in the scene the two are equal.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from neatskin.datasets.paths import PHYSICAL_LIMIT
from neatskin.rig.physlimitnoise import dr_noise_std_ohm
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.sim.daq import SimulatedDAQ
from neatskin.sim.scene import Scene
from neatskin.skin.bound import feature_jacobian, position_bound_mm
from neatskin.skin.model import SkinModel
from neatskin.skin.variability import drift_resistivity_factor

if TYPE_CHECKING:  # pandas and pyarrow are imported when a frame is made: this module stays numpy-only to import
    import pandas as pd
    import pyarrow as pa

METADATA_KEY = b"neatskin.physical_limit"
RESISTIVITY_TEMPCO_PER_K = -0.02  # the skin model's default, used when the skin does not say
POSITION_CHUNK = 128  # positions evaluated at once: the skin's work arrays stay this size as campaigns grow


@dataclass(frozen=True)
class NuisancePriors:
    """Prior std of each nuisance per press: 0 = known exactly (assumed values are named in `basis`)."""

    depth_std_mm: float
    drift_std: float  # std of log(rho / rho0) over the campaign's presses
    placement_std_mm: float  # per axis
    basis: str = ""

    @classmethod
    def from_scene(
        cls, scene: Scene, campaign_s: float, tempco_per_k: float = RESISTIVITY_TEMPCO_PER_K
    ) -> NuisancePriors:
        """The scene's depth jitter and placement error as they are; the drift as the std of log rho over a
        campaign of `campaign_s` seconds, the drift being a ramp sampled uniformly by the presses
        (ptp / sqrt(12))."""
        temperature = float(getattr(scene, "temperature_drift_k_per_h", 0.0))
        evaporation = float(getattr(scene, "evaporation_fraction_per_h", 0.0))
        t = np.linspace(0.0, max(campaign_s, 0.0), 65)
        log_rho = np.log(drift_resistivity_factor(t, temperature, evaporation, tempco_per_k))
        drift = float(np.ptp(log_rho) / np.sqrt(12.0))
        basis = (
            f"depth_std_mm = scene depth_jitter_mm; placement_std_mm = scene placement_error_mm (per axis, "
            f"the labels hold the commanded position); drift_std = ptp(log rho) / sqrt(12) over the campaign's "
            f"{campaign_s:.0f} s (assumed: a ramp sampled uniformly by the presses; temperature "
            f"{temperature:g} K/h at {tempco_per_k:g} /K, evaporation {evaporation:g} /h); the press's own "
            "noise std per pair as for crb_mm; fabrication spread, displaced fluid and relaxation are "
            "not nuisances here (assumed known to the estimator)"
        )
        return cls(
            depth_std_mm=float(getattr(scene, "depth_jitter_mm", 0.0)),
            drift_std=drift,
            placement_std_mm=float(getattr(scene, "placement_error_mm", 0.0)),
            basis=basis,
        )

    def as_kwargs(self) -> dict[str, float]:
        """The keyword arguments of `neatskin.skin.bound.position_bound_mm`."""
        return {k: v for k, v in asdict(self).items() if k != "basis"}


def physical_limit_frame(
    ids: np.ndarray,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    jacobian: np.ndarray,
    noise_std_ohm: np.ndarray,
    priors: NuisancePriors,
) -> pd.DataFrame:
    """position_id, x_mm, y_mm, crb_mm (electronics only) and crb_nuisance_mm, one row per position, from a
    (positions, pairs, 4) `feature_jacobian` and the (positions, pairs) noise std, in one batch."""
    import pandas as pd

    return pd.DataFrame(
        {
            "position_id": np.asarray(ids).astype(np.int32),
            "x_mm": np.asarray(x_mm, float),
            "y_mm": np.asarray(y_mm, float),
            "crb_mm": _bound_mm(jacobian, noise_std_ohm, {}),
            "crb_nuisance_mm": _bound_mm(jacobian, noise_std_ohm, priors.as_kwargs()),
        }
    )


def floors_frame(
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    jacobian: np.ndarray,
    noise_std_ohm: np.ndarray,
    priors: NuisancePriors,
    reference_xy_mm: np.ndarray,
    *,
    fabrication_jacobian: np.ndarray | None = None,
    fabrication_std: float = 0.0,
    seed: int = 0,
) -> pd.DataFrame:
    """The landing-point bound and the label-noise floor per split, one row per position (columns as the module
    says). jacobian: (positions, pairs, 4) `feature_jacobian`; fabrication_jacobian: (positions, pairs, channels)
    d dR / d log h; reference_xy_mm: a large sample of the position strategy (the prior over new positions)."""
    import pandas as pd

    from neatskin.baselines.floors import label_noise_floor, landing_point_bound_mm

    xy = np.column_stack([np.asarray(x_mm, float), np.asarray(y_mm, float)])
    jac, nuisance = np.asarray(jacobian, float), [priors.depth_std_mm, priors.drift_std]
    if fabrication_jacobian is not None and fabrication_std > 0:
        jac = np.concatenate([jac, np.asarray(fabrication_jacobian, float)], axis=2)
        nuisance += [fabrication_std] * fabrication_jacobian.shape[2]
    if np.all(np.asarray(noise_std_ohm) > 0):
        landing = landing_point_bound_mm(jac, noise_std_ohm, np.array(nuisance))
        known_skin = landing_point_bound_mm(jacobian, noise_std_ohm, np.array(nuisance[:2]))
    else:  # no measurement noise: an identifiable landing point is measured exactly
        landing = known_skin = np.zeros(len(xy))
    new = label_noise_floor(xy, reference_xy_mm, priors.placement_std_mm, seed=seed)
    by_row = label_noise_floor(xy, xy, priors.placement_std_mm, seed=seed)
    return pd.DataFrame(
        {
            "landing_bound_mm": landing,
            "landing_bound_known_skin_mm": known_skin,
            "label_floor_new_positions_mean_mm": new.mean_mm,
            "label_floor_new_positions_rms_mm": new.rms_mm,
            "label_floor_by_row_mean_mm": by_row.mean_mm,
            "label_floor_by_row_rms_mm": by_row.rms_mm,
        }
    )


def fabrication_jacobian(
    skin: SkinModel, x_mm: np.ndarray, y_mm: np.ndarray, depth_mm: np.ndarray, step: float = 0.01
) -> np.ndarray:
    """d dR / d log(channel height) per channel, (positions, pairs, channels), by central differences on copies
    of the skin with one channel's height factor scaled by exp(+-step)."""
    import dataclasses

    base = (
        np.ones(skin.layout.n_channels)
        if skin.channel_height_factor is None
        else np.asarray(skin.channel_height_factor, float)
    )
    columns = []
    for c in range(skin.layout.n_channels):
        dr = []
        for sign in (1.0, -1.0):
            heights = base.copy()
            heights[c] *= np.exp(sign * step)
            s = dataclasses.replace(skin, channel_height_factor=tuple(heights))
            dr.append(np.asarray(s.pair_resistance_ohm(x_mm, y_mm, depth_mm), float) - s.baseline_pair_resistance_ohm)
        with np.errstate(invalid="ignore"):  # a pair cut off on both sides: inf - inf, NaN = no information
            columns.append((dr[0] - dr[1]) / (2 * step))
    return np.stack(columns, axis=-1)


def reference_positions_mm(protocol: CampaignProtocol, count: int = 5000) -> np.ndarray:
    """A large sample of the protocol's position strategy, with another seed: the prior over new positions."""
    import dataclasses

    from neatskin.gcode.positions import generate_positions

    spec = protocol.press.positions
    if spec.strategy == "grid":  # a grid's new positions are its own: no other draw exists
        return generate_positions(protocol.layout, spec).xy_mm
    bigger = dataclasses.replace(spec, count=count, seed=spec.seed + 10**6, min_spacing_mm=0.0)
    return generate_positions(protocol.layout, bigger).xy_mm


def _bound_mm(jacobian: np.ndarray, noise_std_ohm: np.ndarray, priors: dict[str, float]) -> np.ndarray:
    """The bound per position; a scene without measurement noise (`noise = false`) measures an identifiable
    position, depth and drift exactly, so only the placement error (per axis, on top) is left."""
    if np.all(np.asarray(noise_std_ohm) > 0):
        return position_bound_mm(jacobian, noise_std_ohm, **priors)
    return np.full(jacobian.shape[0], np.sqrt(2.0) * float(priors.get("placement_std_mm", 0.0)))


def write_physical_limit(
    folder: Path,
    protocol: CampaignProtocol,
    plan: Plan,
    skin: SkinModel,
    daq: SimulatedDAQ,
    *,
    table: Callable[[], pa.Table] | None = None,
) -> Path:
    """Per position, the Cramér-Rao bounds on the position error that the simulated skin, its noise and
    the scene's nuisances allow, written durably beside the presses. `table`: the `physical_limit_table` of
    these arguments computed already (the dry rig computes it while the campaign presses), else computed here."""
    from neatskin.datasets.writer import write_table_durably  # pyarrow: this module stays numpy-only to import

    computed = physical_limit_table(protocol, plan, skin, daq) if table is None else table()
    return write_table_durably(folder / PHYSICAL_LIMIT, computed)


def physical_limit_table(protocol: CampaignProtocol, plan: Plan, skin: SkinModel, daq: SimulatedDAQ) -> pa.Table:
    """The physical limit's table (what `write_physical_limit` writes): a pure function of the protocol, the plan
    and the simulated skin and DAQ, none of the presses."""
    import pandas as pd
    import pyarrow as pa

    positions = plan.program.positions
    ids = np.unique(plan.program.presses.position_ids)  # the positions pressed, in id order
    x = np.asarray(positions.x_mm, dtype=float)[ids]
    y = np.asarray(positions.y_mm, dtype=float)[ids]
    depth = np.full(ids.shape, protocol.press.press.depth_mm)
    # beyond the compliance, the AI's reach or the mux rails a pair's reading clips: no graded information
    readable_ohm = daq.config.readable_ohm
    jac = _by_chunks(
        lambda cx, cy, cd: feature_jacobian(skin, cx, cy, cd, max_resistance_ohm=readable_ohm), x, y, depth
    )  # (positions, pairs, 4)
    pressed = _by_chunks(skin.pair_resistance_ohm, x, y, depth)
    std = dr_noise_std_ohm(protocol, plan, skin, daq, x, y, depth, pressed_ohm=pressed)
    # a pair cut off at a position (a channel pinched shut: R = inf, its estimate's spread NaN or inf) reads no
    # graded value there: it drops out of that position's information, and the other pairs keep theirs (a NaN
    # here used to send every position to the noise-free branch: a bound of 0)
    unread = ~np.isfinite(std)
    jac = np.where(unread[..., None], np.nan, jac)
    std = np.where(unread, 1.0, std)
    priors = NuisancePriors.from_scene(
        protocol.scene,
        _campaign_s(protocol, plan),
        float(getattr(skin, "resistivity_tempco_per_k", RESISTIVITY_TEMPCO_PER_K)),
    )
    frame = physical_limit_frame(ids, x, y, jac, std, priors)
    fabrication = float(getattr(protocol.scene, "fabrication_spread_fraction", 0.0))
    fab_jac = fabrication_jacobian(skin, x, y, depth) if fabrication > 0 and hasattr(skin, "layout") else None
    floors = floors_frame(
        x,
        y,
        jac,
        std,
        priors,
        reference_positions_mm(protocol),
        fabrication_jacobian=fab_jac,
        fabrication_std=fabrication,
        seed=protocol.seed,
    )
    frame = pd.concat([frame, floors], axis=1)
    table = pa.Table.from_pandas(frame, preserve_index=False)
    meta = {
        "crb_mm": "electronics noise only: depth, drift and landing point known",
        "crb_nuisance_mm": "depth, drift and placement as nuisance parameters with the priors below (kept for older "
        "readers: its placement term is the label noise, see landing_bound_mm and label_floor_*)",
        "landing_bound_mm": "landing-point bound: Cramér-Rao bound on where the press landed, with electronics noise, "
        "depth jitter, fluid drift and fabrication spread (log channel heights, prior std fabrication_std) as "
        "nuisances",
        "label_floor_new_positions_mean_mm": "label-noise floor for new positions (grouped split): Bayes mean "
        "Euclidean error against the commanded position, prior = the position strategy (a 5,000-draw sample)",
        "label_floor_by_row_mean_mm": "label-noise floor for the split by row: the same with the prior = the "
        "campaign's own positions; *_rms_mm: the Bayes RMS error (posterior mean)",
        "landing_bound_known_skin_mm": "the same with the skin's fabrication known (a model trained on this skin "
        "learns its channels): electronics noise, depth jitter and drift as nuisances",
        "fabrication_std": fabrication,
        "priors": priors.as_kwargs(),
        "basis": priors.basis,
        "depth_mm": float(protocol.press.press.depth_mm),
    }
    return table.replace_schema_metadata({**(table.schema.metadata or {}), METADATA_KEY: json.dumps(meta).encode()})


def _by_chunks(
    evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    x: np.ndarray,
    y: np.ndarray,
    depth: np.ndarray,
) -> np.ndarray:
    """evaluate(x, y, depth) over POSITION_CHUNK positions at a time, stacked: each position's row is computed
    on its own, so the result is the one-call result while the memory stays that of one chunk."""
    if len(x) <= POSITION_CHUNK:
        return np.asarray(evaluate(x, y, depth), float)
    parts = [
        np.asarray(evaluate(x[k : k + POSITION_CHUNK], y[k : k + POSITION_CHUNK], depth[k : k + POSITION_CHUNK]), float)
        for k in range(0, len(x), POSITION_CHUNK)
    ]
    return np.concatenate(parts)


def _campaign_s(protocol: CampaignProtocol, plan: Plan) -> float:
    """The campaign's duration for the drift: presses x the scene's press interval, else the G-code's time."""
    interval_s = float(getattr(protocol.scene, "press_interval_s", 0.0))
    if interval_s:
        return interval_s * plan.n_presses
    return float(plan.printer_time_s)

"""One candidate's evaluation, a pure function of the study and the candidate (so a local and a Dask run agree):
its layout and placement (optimised here when asked), the bound map over a press grid with depth as nuisance and
its summary, the sweep time, the campaign protocol's electrical check (design/electrical.py), and optionally a
learned error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from neatskin.acquisition.daq.base import DaqConfig
from neatskin.design.bound import (
    PairNoise,
    bound_mm,
    criterion,
    fisher,
    position_information,
    summarise_mm,
)
from neatskin.design.candidates import Candidate, optimiser_junctions
from neatskin.design.cost import candidate_work
from neatskin.design.electrical import candidate_electrical, electrical_columns
from neatskin.design.inversion import inversion_errors_mm
from neatskin.design.learned import learned_error_mm
from neatskin.design.optimise import RIDGE_PER_MM2, PairInformation, greedy_exchange
from neatskin.design.sensitivity import grounded_inverse, press_jacobian
from neatskin.design.study import Study
from neatskin.layout import Layout
from neatskin.skin.layouts import grid_layout


@dataclass(frozen=True)
class CandidateResult:
    """A candidate's row of candidates.parquet and its map (one row per press of the grid)."""

    candidate_id: str
    row: dict[str, Any]
    map_frame: pd.DataFrame


def candidate_layout(study: Study, candidate: Candidate, nodes: tuple[tuple[int, int], ...]) -> Layout:
    return grid_layout(
        candidate.nx,
        candidate.ny,
        pitch_mm=candidate.pitch_mm,
        width_mm=candidate.channel_width_mm,
        height_mm=candidate.channel_height_mm,
        electrodes=list(nodes),
        resistivity_ohm_m=study.resistivity_ohm_m,
        thickness_mm=study.thickness_mm,
        channel_depth_mm=study.channel_depth_mm,
    )


def canonical_nodes(nodes: tuple[tuple[int, int], ...]) -> tuple[tuple[int, int], ...]:
    """Electrodes numbered in junction order (row by row): the same set gives the same pairs in the same order, so
    the same noise draws, whatever order a placement lists them in (the learned error depends on it: the boundary
    walk's order gave `design validate` 4.90 where the study reported 4.88 mm for the same 12 electrodes)."""
    return tuple(sorted(nodes, key=lambda n: (n[1], n[0])))


def press_grid_mm(layout: Layout, per_axis: int) -> tuple[np.ndarray, np.ndarray]:
    """A cell-centred press grid over the layout's bounds (no press exactly on the outer channels), x fastest."""
    x0, y0, x1, y1 = layout.bounds_mm
    xs = x0 + (np.arange(per_axis) + 0.5) * (x1 - x0) / per_axis
    ys = y0 + (np.arange(per_axis) + 0.5) * (y1 - y0) / per_axis
    gx, gy = np.meshgrid(xs, ys)
    return gx.ravel(), gy.ravel()


def pair_noise(study: Study) -> PairNoise:
    lsb = DaqConfig(amplitude_a=study.amplitude_a).lsb_ai_v * DaqConfig(amplitude_a=study.amplitude_a).to_physical
    return PairNoise(
        model=study.noise_model,
        std_ohm=study.noise_std_ohm,
        voltage_noise_v=study.voltage_noise_v,
        current_noise_a=study.current_noise_a,
        voltage_lsb_v=float(lsb[0]) if study.quantise else 0.0,
        current_lsb_a=float(lsb[1]) if study.quantise else 0.0,
        amplitude_a=study.amplitude_a,
        live_samples=study.live_samples,
        sweeps_per_press=study.sweeps_per_press,
    )


def evaluate_candidate(
    study: Study, candidate: Candidate, tick: Callable[[float], None] | None = None
) -> CandidateResult:
    """Evaluate one candidate (pure: same inputs, same numbers). tick(share) is told the share of the candidate's
    work just done, per tile of presses, learned seed and inversion step (design/cost.py counts the work)."""
    units = _ticker(study, candidate, tick)
    radius = candidate.probe_diameter_mm / 2.0
    noise = pair_noise(study)
    if candidate.strategy == "optimised":
        pool = optimiser_junctions(candidate.nx, candidate.ny)
        layout = candidate_layout(study, candidate, tuple(pool[:2]))
    else:
        pool = list(candidate.nodes)
        layout = candidate_layout(study, candidate, candidate.nodes)
    x, y = press_grid_mm(layout, study.press_grid)
    index = {(i, j): j * candidate.nx + i for j in range(candidate.ny) for i in range(candidate.nx)}
    z = grounded_inverse(layout)
    pj = press_jacobian(
        layout,
        np.array([index[n] for n in pool]),
        x,
        y,
        candidate.depth_mm,
        radius,
        study.fidelity,
        z=z,
        on_presses=lambda n: units(n * len(pool)),
    )
    table = PairInformation(pj, noise)
    evaluations = 0
    if candidate.strategy == "optimised":
        placement = greedy_exchange(table, candidate.count, study.criterion, study.restarts, study.seed)
        members = np.array(placement.members)
        evaluations = placement.evaluations
    else:
        members = np.arange(len(pool))
    nodes = tuple(pool[k] for k in members)
    a, b = np.triu_indices(len(members), 1)
    ea, eb = members[a], members[b]
    jac = pj.pair_jacobian(ea, eb)  # (presses, pairs, 3)
    sigma = noise.std(pj.baseline_pair_ohm[ea, eb])
    info = fisher(jac, sigma)
    info_nuisance = position_information(info)
    bound = bound_mm(info_nuisance)
    bound_known = bound_mm(position_information(info, depth_known=True))
    pressed = pj.pressed_pair_ohm(ea, eb)
    max_pair_ohm = float(max(np.max(pressed), np.max(pj.baseline_pair_ohm[ea, eb])))
    # electrodes numbered in junction order: the same set draws the same noise, whatever the placement's order
    canonical = canonical_nodes(nodes)
    placed = layout if candidate.strategy != "optimised" else candidate_layout(study, candidate, canonical)
    electrical = candidate_electrical(study, placed)
    pairs = int(a.size)
    slot = study.break_samples + study.settle_samples + study.live_samples
    cap = candidate.pitch_mm / 2.0
    summary = summarise_mm(bound)
    row: dict[str, Any] = {
        "candidate_id": candidate.candidate_id,
        "nx": candidate.nx,
        "ny": candidate.ny,
        "pitch_mm": candidate.pitch_mm,
        "channel_width_mm": candidate.channel_width_mm,
        "channel_height_mm": candidate.channel_height_mm,
        "probe_diameter_mm": candidate.probe_diameter_mm,
        "depth_mm": candidate.depth_mm,
        "strategy": candidate.strategy,
        "placement": candidate.placement,
        "electrodes": int(len(members)),
        "pairs": pairs,
        "electrode_nodes": ";".join(f"{i},{j}" for i, j in nodes),
        **summary,
        "bound_mean_capped_mm": float(np.mean(np.minimum(bound, cap))),
        "bound_cap_mm": cap,
        "bound_known_depth_median_mm": float(np.median(bound_known)),
        "criterion_D": float(criterion(info_nuisance, "D", RIDGE_PER_MM2)),
        "criterion_A": float(criterion(info_nuisance, "A", RIDGE_PER_MM2)),
        "optimiser_evaluations": int(evaluations),
        "presses": int(x.size),
        "sweep_time_s": pairs * slot / study.rate_hz,
        "noise_std_median_ohm": float(np.median(sigma)),
        "rails_v": study.rails_v,
        **electrical_columns(electrical, max_pair_ohm, study.press_margin),
        "learned_error_mean_mm": math.nan,
        "learned_error_std_mm": math.nan,
        "learned_seeds": 0,
    }
    if study.learned.enabled:
        errors = learned_error_mm(candidate_layout(study, candidate, canonical), study, candidate, noise, units)
        row.update(
            learned_error_mean_mm=float(np.mean(errors)),
            learned_error_std_mm=float(np.std(errors, ddof=1)) if errors.size > 1 else math.nan,
            learned_seeds=int(errors.size),
        )
    map_columns = {
        "candidate_id": candidate.candidate_id,
        "x_mm": x,
        "y_mm": y,
        "bound_mm": bound,
        "bound_known_depth_mm": bound_known,
    }
    row.update(
        inversion_error_mean_mm=math.nan,
        inversion_error_std_mm=math.nan,
        inversion_error_median_mm=math.nan,
        inversion_error_p90_mm=math.nan,
    )
    if study.inversion.enabled:
        electrode_junctions = pj.junctions[members]
        errors = inversion_errors_mm(
            layout, electrode_junctions, x, y, candidate.depth_mm, radius, study.fidelity, noise, z,
            study.inversion, study.seed, units,
        )  # fmt: skip
        per_draw = errors.mean(axis=1)
        row.update(
            inversion_error_mean_mm=float(per_draw.mean()),
            inversion_error_std_mm=float(np.std(per_draw, ddof=1)) if per_draw.size > 1 else math.nan,
            inversion_error_median_mm=float(np.median(errors)),
            inversion_error_p90_mm=float(np.percentile(errors, 90)),
        )
        map_columns["inversion_error_mm"] = errors.mean(axis=0)
    map_frame = pd.DataFrame(map_columns)
    units(0, done=True)
    return CandidateResult(candidate.candidate_id, row, map_frame)


def _ticker(study: Study, candidate: Candidate, tick: Callable[[float], None] | None) -> Callable[..., None]:
    """units(n) turns n press evaluations into the share of the candidate's work for tick; units(0, done=True)
    gives what is left (the estimate's rounding), so a candidate always adds up to exactly 1."""
    if tick is None:
        return lambda n, done=False: None
    total = max(1, candidate_work(study, candidate).total)
    given = 0.0

    def units(n: int, done: bool = False) -> None:
        nonlocal given
        share = 1.0 - given if done else min(n / total, 1.0 - given)
        given += share
        if share > 0:
            tick(share)

    return units

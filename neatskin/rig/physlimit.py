"""The physical limit of a dry run: per position, the Cramér-Rao bound on the position error that the
simulated skin and its noise allow (physical_limit.parquet, beside the presses)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neatskin.rig.folder import PHYSICAL_LIMIT
from neatskin.rig.protocol import Protocol


def write_physical_limit(folder: Path, protocol: Protocol, plan, rig) -> Path:
    """Per position, the Cramér-Rao bound on the position error that the simulated skin and noise allow."""
    import pandas as pd
    import pyarrow as pa

    from neatskin.baselines.crb import cramer_rao_bound_mm
    from neatskin.datasets.writer import write_table_durably

    blocks = {b.position_id: b for b in plan.program.presses}
    ids = np.array(sorted(blocks))
    x = np.array([blocks[i].x_mm for i in ids])
    y = np.array([blocks[i].y_mm for i in ids])
    depth = np.full(ids.shape, protocol.press.press.depth_mm)
    jac = rig.skin.jacobian_mm(x, y, depth)  # (positions, pairs, 2) ohm / mm
    std = _dr_noise_std_ohm(protocol, plan, rig, x, y, depth)
    crb = np.array([cramer_rao_bound_mm(jac[k : k + 1], noise_std=std[k])[0] for k in range(len(ids))])
    table = pa.Table.from_pandas(
        pd.DataFrame({"position_id": ids.astype(np.int32), "x_mm": x, "y_mm": y, "crb_mm": crb}), preserve_index=False
    )
    return write_table_durably(folder / PHYSICAL_LIMIT, table)


def _dr_noise_std_ohm(protocol, plan, rig, x, y, depth) -> np.ndarray:
    """Std of one press's dR per pair (positions, pairs): the estimator noise of the baseline and pressed sweeps
    that a press averages, drawn from the simulated DAQ's features path at the unpressed and pressed states."""
    from neatskin.sim.daq import SimulatedDAQ

    sweep, draws = plan.sweep, 64
    pressed = rig.skin.pair_resistance_ohm(x, y, depth)
    states = np.vstack([np.asarray(rig.skin.baseline_pair_resistance_ohm)[None], pressed])  # (1 + positions, pairs)
    var = np.empty_like(states)
    for k, state in enumerate(states):

        def constant(t: np.ndarray, s: np.ndarray = state) -> np.ndarray:
            return np.broadcast_to(s, (len(t), s.size))

        daq = SimulatedDAQ(rig.daq.config, constant, noise=rig.daq.noise)
        est = daq.estimate_sweep(
            sweep,
            np.random.default_rng([protocol.seed, 10**6, k]),
            0.0,
            method=protocol.acquisition.demodulation,
            window=protocol.acquisition.window,
            n_sweeps=draws,
        )
        var[k] = est.resistance_ohm.var(axis=0)
    durations = _typical_phases_s(plan, protocol)
    n_base = max(1, int(durations[1] // sweep.duration_s))  # sweeps while descending through air
    n_press = max(1, int(plan.hold_s // sweep.duration_s) - 1)  # whole sweeps inside the hold
    return np.sqrt(var[0] / n_base + var[1:] / n_press)


def _typical_phases_s(plan, protocol) -> np.ndarray:
    from neatskin.gcode.motion import phase_durations_s

    return np.median(phase_durations_s(plan.program, protocol.printer), axis=0)

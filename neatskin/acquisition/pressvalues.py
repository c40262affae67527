"""A press's per-pair values from its sweeps: the baseline (every sweep that ended before the probe reached the
surface, the `contact` mark) and the pressed value (every sweep inside the hold, `hold_start` .. `hold_end`),
their difference and the flags of the sweeps used.

A pure function of the pair estimates and the marks, so it runs where the estimates are: in the main process
for the real rig and the inline dry run, in the skin worker's process beside a dry run (neatskin.sim.skinworker),
which then sends the press's values with its estimates; the same function, the same bits.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from neatskin.acquisition.estimates import PairEstimates, PairFlag, flag_names


@dataclass(frozen=True)
class PressValues:
    resistance_ohm: np.ndarray  # (pairs,) pressed
    baseline_ohm: np.ndarray  # (pairs,)
    delta_r_ohm: np.ndarray  # (pairs,)
    flags: tuple[str, ...]
    n_baseline: int
    n_pressed: int


def press_values(estimates: PairEstimates, marks: dict[str, int], pair_labels: Sequence[str]) -> PressValues:
    """Per pair, the mean of the baseline sweeps and of the pressed sweeps (inf when any of them is an open
    circuit or clipped, NaN when there is none), their difference and the flags of the sweeps used.

    A clipped sweep (the AI's range, or the mux rails: the switch clamped, so V / I is not the skin's R) is no
    value: the pair's mean is +inf as a cut pair's, never a finite reading that looks valid (its per-sweep
    estimate keeps its finite value, and the waveforms when recorded, for a curator)."""
    baseline_use, pressed_use = sweeps_used(estimates.windows, marks)
    use = np.stack([baseline_use, pressed_use])  # (2, sweeps, pairs): baseline, pressed
    r = estimates.resistance_ohm
    count = use.sum(axis=1)
    with np.errstate(invalid="ignore"):
        total = np.where(use, r, 0.0).sum(axis=1)
    clipped = (estimates.flags & np.uint8(PairFlag.CLIPPED)) != 0
    open_circuit = (use & (np.isinf(r) | clipped)).any(axis=1)
    mean = np.where(open_circuit, np.inf, total / np.maximum(count, 1))
    (r_b, r_p) = np.where(count > 0, mean, np.nan)
    bits = np.bitwise_or.reduce(np.where(use, estimates.flags, 0).astype(np.uint8), axis=(0, 1))
    flags: list[str] = []
    if not baseline_use.any():
        flags.append("no_baseline_sweep")
    if not pressed_use.any():
        flags.append("no_pressed_sweep")
    both_open = np.isinf(r_b) & np.isinf(r_p)
    with np.errstate(invalid="ignore"):
        delta = np.where(both_open, 0.0, r_p - r_b)
    for pair in np.flatnonzero(bits).tolist():
        flags.extend(f"{name}:{pair_labels[pair]}" for name in _flag_names(int(bits[pair])))
    return PressValues(
        r_p, r_b, delta, tuple(flags), int(baseline_use.any(axis=1).sum()), int(pressed_use.all(axis=1).sum())
    )


def sweeps_used(windows: np.ndarray, marks: Mapping[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Which estimates a press's values average, (sweeps, pairs) bool each: the baseline's (the pair's live window
    ended before the probe reached the surface, `contact`) and the pressed value's (the live window lies wholly
    inside the hold, `hold_start` .. `hold_end`). Per pair, not per sweep: a pair whose live window falls inside
    the hold counts although the sweep it belongs to began before the hold or ends after it (so a 1.2 s hold of
    0.34 s sweeps gives each pair 3 or 4 pressed estimates, not the 3 whole sweeps). The physical limit's reading
    noise counts the same way (neatskin.rig.physlimitnoise)."""
    start, stop = windows[..., 0], windows[..., 1]
    baseline_use = stop <= marks["contact"]
    pressed_use = (start >= marks["hold_start"]) & (stop <= marks["hold_end"])
    return baseline_use, pressed_use


@functools.lru_cache(maxsize=256)
def _flag_names(bits: int) -> tuple[str, ...]:
    return flag_names(bits)

"""The per-pair resistance estimate type shared by the demodulator and the simulated DAQ's features-only path.

Arrays are batch first: (sweeps, pairs), pairs in layout.pairs order. Flags are bit flags
(uint8). An open circuit (near-zero current) reports resistance_ohm = +inf and
uncertainty_ohm = +inf, never NaN; every other flagged estimate keeps its finite value so a
curator can decide.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class PairFlag(enum.IntFlag):
    OK = 0
    OPEN_CIRCUIT = 1  # current RMS below the open-circuit threshold: resistance = inf
    CLIPPED = 2  # a voltage or current sample at the ADC range limit
    DC_OFFSET = 4  # mean of V or I over the live window above a share of its RMS
    NO_SAMPLES = 8  # the live window is not (wholly) inside the acquisition
    NO_BASELINE = 16  # features: no unpressed window for this pair
    NO_PRESSED = 32  # features: no window of this pair inside the press


def flag_names(flags: int) -> tuple[str, ...]:
    """The names of the bits set in one flags value, e.g. ('OPEN_CIRCUIT',)."""
    return tuple(str(f.name).lower() for f in PairFlag if f and int(flags) & f)


@dataclass(frozen=True, eq=False)
class PairEstimates:
    """Resistance per sweep and pair, its uncertainty, flags and the sample windows it came from.

    windows: (sweeps, pairs, 2) [start, stop) in the acquisition's global sample index.
    """

    resistance_ohm: np.ndarray
    uncertainty_ohm: np.ndarray
    flags: np.ndarray
    windows: np.ndarray = field(repr=False)
    method: str = "lockin"

    def __post_init__(self) -> None:
        shape = np.shape(self.resistance_ohm)
        if len(shape) != 2:
            raise ValueError(f"resistance_ohm must be (sweeps, pairs), got shape {shape}")
        if np.shape(self.uncertainty_ohm) != shape or np.shape(self.flags) != shape:
            raise ValueError("resistance_ohm, uncertainty_ohm and flags must share one (sweeps, pairs) shape")
        if np.shape(self.windows) != (*shape, 2):
            raise ValueError("windows must be (sweeps, pairs, 2)")
        if np.isnan(self.resistance_ohm).any() or np.isnan(self.uncertainty_ohm).any():
            raise ValueError("estimates carry no NaN: an open circuit is +inf with the OPEN_CIRCUIT flag")

    @property
    def n_sweeps(self) -> int:
        return int(self.resistance_ohm.shape[0])

    @property
    def n_pairs(self) -> int:
        return int(self.resistance_ohm.shape[1])

    def flag_names(self) -> list[list[tuple[str, ...]]]:
        return [[flag_names(f) for f in row] for row in self.flags]

    @staticmethod
    def concatenate(parts: list[PairEstimates]) -> PairEstimates:
        """Stack the sweeps of several estimates (same pairs, same method)."""
        return PairEstimates(
            np.concatenate([p.resistance_ohm for p in parts]),
            np.concatenate([p.uncertainty_ohm for p in parts]),
            np.concatenate([p.flags for p in parts]),
            np.concatenate([p.windows for p in parts]),
            parts[0].method,
        )

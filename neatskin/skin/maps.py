"""Sensitivity maps (paper eq. 2): the change in R_eq of every electrode pair per press position,
from the paper's simulation (each channel +50 % in turn) or from the deformation model on a grid.

z(x, y) = max over S of dR_eq(x, y), normalised to [-1, 1] by the largest |dR_eq| on the map;
per-pair maps are normalised the same way, each by its own largest |dR_eq|. Pure computation:
plotting lives in `plots.py`, files in `cli.py`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neatskin.layout import ElectrodePair, Layout
from neatskin.skin.channelchange import undeformed_channel_change_delta_ohm
from neatskin.skin.layoutcache import LayoutCache, per_layout
from neatskin.skin.model import SkinModel


@dataclass(frozen=True)
class SensitivityMap:
    """dR_eq (ohm) of every pair (layout.pairs order) at each press position."""

    source: str
    x_mm: np.ndarray  # (n,)
    y_mm: np.ndarray  # (n,)
    delta_ohm: np.ndarray  # (n, pairs)
    pairs: tuple[ElectrodePair, ...]

    def __init__(
        self, source: str, x_mm: np.ndarray, y_mm: np.ndarray, delta_ohm: np.ndarray, pairs: tuple[ElectrodePair, ...]
    ) -> None:
        # written out (dataclass keeps a class's own __init__): the generated frozen one sets each field through
        # object.__setattr__ and then calls __post_init__, a third of a paper map's time outside the arithmetic
        n = x_mm.shape[0]
        if y_mm.shape != (n,) or delta_ohm.shape != (n, len(pairs)):
            raise ValueError(
                f"inconsistent map shapes: x {x_mm.shape}, y {y_mm.shape}, delta {delta_ohm.shape}, {len(pairs)} pairs"
            )
        fields = self.__dict__
        fields["source"], fields["x_mm"], fields["y_mm"] = source, x_mm, y_mm
        fields["delta_ohm"], fields["pairs"] = delta_ohm, pairs

    @property
    def z(self) -> np.ndarray:
        """Paper eq. 2: max over S of dR_eq, normalised to [-1, 1] over the map, (n,)."""
        z = self.delta_ohm.max(axis=1)
        return z / np.max(np.abs(z))

    def pair_normalised(self, pair: ElectrodePair) -> np.ndarray:
        """One pair's dR_eq normalised to [-1, 1] by its own largest magnitude, (n,)."""
        d = self.delta_ohm[:, self.pairs.index(pair)]
        return d / np.max(np.abs(d))

    def to_frame(self):
        """One row per position: source, x_mm, y_mm, z, and dR_ohm_<i>_<j> per pair."""
        import pandas as pd

        data = {"source": self.source, "x_mm": self.x_mm, "y_mm": self.y_mm, "z": self.z}
        data.update({f"dR_ohm_{p.i}_{p.j}": self.delta_ohm[:, k] for k, p in enumerate(self.pairs)})
        return pd.DataFrame(data)


def channel_midpoints_mm(layout: Layout) -> np.ndarray:
    """Midpoint of each channel's centre line, (channels, 2)."""
    xy = layout.xy_mm
    return 0.5 * (xy[layout.channel_ends[:, 0]] + xy[layout.channel_ends[:, 1]])


def paper_sensitivity(layout: Layout, increase: float = 0.5) -> SensitivityMap:
    """The paper's simulation: each channel's resistance raised by `increase` (+50 %) in turn; one
    'press' per channel, placed at the channel's midpoint (paper Fig. 3, black dots). The changes come from
    rank-one updates of one grounded inverse (`channelchange.channel_change_delta_ohm`), not 13 full solves."""
    delta = undeformed_channel_change_delta_ohm(layout, 1.0 + increase)
    entry = _MIDPOINTS.get(id(layout))  # per_layout's hit path inlined (a call saved on a map of a few microseconds)
    x_mm, y_mm = entry[1] if entry and entry[0]() is layout else per_layout(_MIDPOINTS, layout, _read_only_midpoints)
    source = _PAPER_SOURCE if increase == 0.5 else f"paper_plus{round(increase * 100)}pct"  # the f-string: 1 us
    return SensitivityMap(source, x_mm, y_mm, delta, layout.pairs)


_PAPER_SOURCE = "paper_plus50pct"


# per layout object: the channel midpoints' x and y, read only (shared by every paper map of the layout)
_MIDPOINTS: LayoutCache[tuple[np.ndarray, np.ndarray]] = {}


def _read_only_midpoints(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    mid = channel_midpoints_mm(layout)
    x_mm, y_mm = mid[:, 0].copy(), mid[:, 1].copy()
    x_mm.flags.writeable = False
    y_mm.flags.writeable = False
    return x_mm, y_mm


def grid_positions_mm(layout: Layout, step_mm: float, margin_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A regular grid over the layout's bounds (plus margin), x fastest; returns flat x, y arrays."""
    if not step_mm > 0:
        raise ValueError(f"grid step must be > 0 mm, got {step_mm}")
    x0, y0, x1, y1 = layout.bounds_mm
    xs = np.arange(x0 - margin_mm, x1 + margin_mm + step_mm / 2, step_mm)
    ys = np.arange(y0 - margin_mm, y1 + margin_mm + step_mm / 2, step_mm)
    gx, gy = np.meshgrid(xs, ys)
    return gx.ravel(), gy.ravel()


def deformation_sensitivity(
    model: SkinModel,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    depth_mm: float = 3.5,
    batch: int = 4096,
    progress: Callable[[int], object] | None = None,
) -> SensitivityMap:
    """dR_eq of a press at every (x, y) to depth_mm under `model`; `progress(k)` is told of each
    finished batch of k presses (for a progress bar at the edge)."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    base = model.baseline_pair_resistance_ohm
    delta = np.empty((x.shape[0], base.shape[0]))
    for lo in range(0, x.shape[0], batch):
        sl = slice(lo, lo + batch)
        delta[sl] = model.pair_resistance_ohm(x[sl], y[sl], np.full(x[sl].shape, depth_mm)) - base
        if progress is not None:
            progress(x[sl].shape[0])
    return SensitivityMap(f"{model.fidelity}_{depth_mm:g}mm", x, y, delta, model.layout.pairs)

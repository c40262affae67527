"""Fitting the skin model to a recorded campaign: channel baselines, pinch, placement, noise and drift, with intervals.

Steps, each a least-squares problem through the forward model (`SkinModel`):
1. drift: every press's baseline R_eq (R - dR, measured in air just before it) against its
   campaign time, log R = log R0 + k t per pair; k is the shared slope (per hour).
2. channel baselines: the drift-corrected mean baseline of every pair against the network
   solver, one resistance per channel (`scipy.optimize.least_squares` in log R).
3. pinch: the per-position mean dR against the deformation model with those channels
   (pinch_gain, decay_ratio).
4. placement and noise: the variance of dR over a position's repeats is, to first order,
   noise^2 + s_p^2 |d dR / d(x, y)|^2 per pair; a non-negative linear fit across positions and
   pairs gives both.
Intervals are +-1.96 standard errors from the local Jacobian (s^2 (J^T J)^-1). A parameter the
data cannot separate from the others (a singular direction of J^T J) is named in a DataError,
not returned as a number.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neatskin.errors import DataError
from neatskin.layout import Layout, load_layout
from neatskin.skin.deformation import PinchParams
from neatskin.skin.model import SkinModel
from neatskin.skin.network import equivalent_resistance

Z95 = 1.96
MIN_POSITIONS_FOR_PINCH = 4


@dataclass(frozen=True)
class FittedValue:
    value: float
    ci95: tuple[float, float]


@dataclass(frozen=True)
class SkinFit:
    """A skin fitted to one campaign: every parameter with its 95 % interval, and the pinch's correlation."""

    source: str
    channel_resistance_ohm: tuple[FittedValue, ...]
    pinch_gain: FittedValue
    decay_ratio: FittedValue
    placement_error_mm: FittedValue
    noise_ohm: FittedValue
    drift_per_h: FittedValue
    pinch_correlation: float  # between pinch_gain and decay_ratio
    rms_residual_ohm: float
    notes: tuple[str, ...] = field(default=())

    def to_toml(self) -> str:
        """A skin profile: the fitted values, each with its interval as a comment."""
        lines = [f"# skin profile fitted by `neatskin skin fit` to {self.source}", "[skin_profile]"]
        for name in ("pinch_gain", "decay_ratio", "placement_error_mm", "noise_ohm", "drift_per_h"):
            v = getattr(self, name)
            lines.append(f"{name} = {v.value!r}  # 95 % CI {v.ci95[0]:.4g} .. {v.ci95[1]:.4g}")
        lines.append(
            "channel_resistance_ohm = [" + ", ".join(f"{c.value:.6g}" for c in self.channel_resistance_ohm) + "]"
        )
        lines.append(f"pinch_correlation = {self.pinch_correlation!r}")
        return "\n".join(lines) + "\n"


def _interval(value: float, se: float) -> FittedValue:
    return FittedValue(float(value), (float(value - Z95 * se), float(value + Z95 * se)))


def _covariance(jac: np.ndarray, residual: np.ndarray, names: list[str], source: str) -> np.ndarray:
    """s^2 (J^T J)^-1, or a DataError naming the parameters along a direction the data do not see."""
    jtj = jac.T @ jac
    values, vectors = np.linalg.eigh(jtj)
    weak = values <= 1e-10 * max(values.max(), np.finfo(float).tiny)
    if weak.any():
        loads = np.abs(vectors[:, weak]).max(axis=1)
        culprits = [n for n, w in zip(names, loads) if w > 0.3]
        raise DataError(
            f"{source} cannot identify {', '.join(culprits)}: the presses do not separate "
            f"{'it' if len(culprits) == 1 else 'them'} from the other parameters",
            field=", ".join(culprits),
            fix="record presses at more positions (on and between channels) and in press order over time",
        )
    dof = max(jac.shape[0] - jac.shape[1], 1)
    return float(residual @ residual) / dof * np.linalg.inv(jtj)


def load_campaign(folder: str | Path) -> tuple[Layout, dict, dict[str, np.ndarray]]:
    """The campaign's layout, manifest and press columns (x, y, depth, press time in h, R and dR per pair)."""
    import pandas as pd

    folder = Path(folder)
    table = folder / "presses.parquet"
    if not table.exists():
        raise DataError(f"{folder} has no presses.parquet", field="presses.parquet", fix="fit a finished campaign")
    df = pd.read_parquet(table).sort_values("press_id")
    missing = [c for c in ("x_mm", "y_mm", "depth_mm", "position_id", "press_id") if c not in df.columns]
    if missing:
        raise DataError(
            f"{table} has no {', '.join(missing)} column: the fit needs where each press was",
            field=", ".join(missing),
            fix="fit a campaign recorded with positions (neatskin campaign run writes them)",
        )
    manifest = json.loads((folder / "manifest.json").read_text())
    layout = load_layout(folder / "inputs" / "layout.toml")
    dr = df[[c for c in df.columns if c.startswith("dR_ohm_")]].to_numpy(float)
    r = df[[c for c in df.columns if c.startswith("R_ohm_")]].to_numpy(float)
    interval_h = manifest.get("printer_time_estimate_s", 0.0) / max(len(df), 1) / 3600.0
    columns = {
        "x": df.x_mm.to_numpy(float),
        "y": df.y_mm.to_numpy(float),
        "depth": df.depth_mm.to_numpy(float),
        "position": df.position_id.to_numpy(),
        "hours": df.press_id.to_numpy(float) * interval_h,
        "R": r,
        "dR": dr,
    }
    return layout, manifest, columns


def fit_skin(folder: str | Path, probe_radius_mm: float = 2.75) -> SkinFit:
    """Fit the skin model to the campaign in `folder` (see the module docstring)."""
    from scipy.optimize import least_squares

    layout, _, c = load_campaign(folder)
    source = str(folder)
    base = c["R"] - c["dR"]
    ok = np.all(np.isfinite(base), axis=1) & np.all(np.isfinite(c["dR"]), axis=1)
    if ok.sum() < 3:
        raise DataError(f"{source}: fewer than 3 presses with finite R", field="R_ohm", fix="record more presses")
    hours, base, dr = c["hours"][ok], base[ok], c["dR"][ok]
    x, y, depth, position = c["x"][ok], c["y"][ok], c["depth"][ok], c["position"][ok]
    notes = []
    # 1. drift: log R_base = a_pair + k t
    span = float(np.ptp(hours))
    logb = np.log(base)
    centred_t = hours - hours.mean()
    centred_b = logb - logb.mean(axis=0)
    if span <= 0:
        raise DataError(
            f"{source}: every press has the same campaign time, so no drift rate can be identified",
            field="drift_per_h",
            fix="fit a campaign recorded in press order over time",
        )
    k = float((centred_t[:, None] * centred_b).sum() / (centred_t**2).sum() / base.shape[1])
    resid = centred_b - k * centred_t[:, None]
    se_k = math.sqrt(
        float((resid**2).sum()) / max(resid.size - base.shape[1] - 1, 1) / (base.shape[1] * (centred_t**2).sum())
    )
    # 2. channel baselines from the drift-corrected mean baseline
    target = np.exp(np.mean(logb - k * hours[:, None], axis=0))

    def baseline_residual(log_r):
        return np.log(equivalent_resistance(layout, 1.0 / np.exp(log_r))) - np.log(target)

    start = np.log(layout.channel_resistance_ohm)
    sol = least_squares(baseline_residual, start, method="lm")
    names = [f"channel_resistance_ohm[{ch.name}]" for ch in layout.channels]
    cov_r = _covariance(np.asarray(sol.jac), sol.fun, names, source)
    # the drift slope's error moves every channel's baseline together (target is extrapolated to t = 0)
    cov_r = cov_r + (se_k * float(hours.mean())) ** 2
    r_channels = np.exp(sol.x)
    channels = tuple(
        FittedValue(float(v), (float(v * math.exp(-Z95 * s)), float(v * math.exp(Z95 * s))))
        for v, s in zip(r_channels, np.sqrt(np.diag(cov_r)))
    )
    heights = tuple(float(h) for h in layout.channel_resistance_ohm / r_channels)
    # 3. pinch from the per-position mean dR
    ids, inverse = np.unique(position, return_inverse=True)
    if len(ids) < MIN_POSITIONS_FOR_PINCH:
        raise DataError(
            f"{source} pressed {len(ids)} position(s): pinch_gain, decay_ratio and placement_error_mm "
            "cannot be told apart from where the presses were",
            field="pinch_gain, decay_ratio, placement_error_mm",
            fix=f"record presses at {MIN_POSITIONS_FOR_PINCH} or more positions, on and between channels",
        )
    counts = np.bincount(inverse)
    dr = dr * np.exp(-k * hours)[:, None]  # back to the resistivity at t = 0, where the baselines were fitted
    mean_dr = np.stack([np.bincount(inverse, dr[:, p]) for p in range(dr.shape[1])], axis=1) / counts[:, None]
    px = np.bincount(inverse, x) / counts
    py = np.bincount(inverse, y) / counts
    pd_ = np.bincount(inverse, depth) / counts

    def skin_for(theta, channel_heights=heights) -> SkinModel:
        return SkinModel(
            layout,
            probe_radius_mm=probe_radius_mm,
            pinch=PinchParams(pinch_gain=float(theta[0]), decay_ratio=float(theta[1])),
            channel_height_factor=channel_heights,
        )

    def pinch_residual(theta, channel_heights=heights):
        skin = skin_for(theta, channel_heights)
        model = skin.pair_resistance_ohm(px, py, pd_) - skin.baseline_pair_resistance_ohm
        return np.where(np.isfinite(model), model - mean_dr, 0.0).ravel()

    sol_p = least_squares(pinch_residual, [1.0, 0.5], bounds=([0.05, 0.05], [5.0, 5.0]), x_scale=[0.1, 0.1])
    jac_p = np.asarray(sol_p.jac)
    cov_p = _covariance(jac_p, sol_p.fun, ["pinch_gain", "decay_ratio"], source)
    # the channels' own uncertainty, carried into the pinch by the delta method:
    # d theta / d log R = -(J^T J)^-1 J^T d residual / d log R
    step = 1e-4
    d_res = np.column_stack(
        [
            (
                pinch_residual(sol_p.x, tuple(np.array(heights) * np.exp(-step * (np.arange(len(heights)) == c))))
                - sol_p.fun
            )
            / step
            for c in range(len(heights))
        ]
    )
    gain = -np.linalg.solve(jac_p.T @ jac_p, jac_p.T @ d_res)
    cov_p = cov_p + gain @ cov_r @ gain.T
    se_p = np.sqrt(np.diag(cov_p))
    correlation = float(cov_p[0, 1] / (se_p[0] * se_p[1]))
    # 4. placement and noise from the repeats' variance against |J|^2
    skin = skin_for(sol_p.x)
    jac = skin.jacobian_mm(px, py, pd_)
    grad2 = np.nansum(jac**2, axis=-1)  # (positions, pairs)
    repeats = counts >= 2
    spread = [np.bincount(inverse, (dr[:, p] - mean_dr[inverse, p]) ** 2) for p in range(dr.shape[1])]
    var = np.stack(spread, axis=1) / np.maximum(counts - 1, 1)[:, None]
    a = np.column_stack([np.ones(int(repeats.sum()) * dr.shape[1]), grad2[repeats].ravel()])
    b = var[repeats].ravel()
    keep = np.isfinite(a[:, 1]) & np.isfinite(b)
    from scipy.optimize import nnls

    coef, _ = nnls(a[keep], b[keep])
    res = b[keep] - a[keep] @ coef
    cov_v = float(res @ res) / max(keep.sum() - 2, 1) * np.linalg.pinv(a[keep].T @ a[keep])
    noise, placement = math.sqrt(coef[0]), math.sqrt(coef[1])
    se_noise = math.sqrt(cov_v[0, 0]) / (2 * max(noise, 1e-12))
    se_place = math.sqrt(cov_v[1, 1]) / (2 * max(placement, 1e-12))
    if placement == 0:
        notes.append("placement_error_mm is at its bound 0: the repeats' spread does not grow with the slope")
    return SkinFit(
        source=source,
        channel_resistance_ohm=channels,
        pinch_gain=_interval(sol_p.x[0], se_p[0]),
        decay_ratio=_interval(sol_p.x[1], se_p[1]),
        placement_error_mm=_interval(placement, se_place),
        noise_ohm=_interval(noise, se_noise),
        drift_per_h=_interval(k, se_k),
        pinch_correlation=correlation,
        rms_residual_ohm=float(np.sqrt(np.mean(sol_p.fun**2))),
        notes=tuple(notes),
    )


def load_skin_profile(path: str | Path, layout: Layout, probe_radius_mm: float = 2.75) -> SkinModel:
    """The SkinModel a `[skin_profile]` TOML (written by `neatskin skin fit`) describes on `layout`.

    Every problem is one ConfigError naming the file, the field and the fix; a profile fitted to
    another layout (a different channel count) is refused."""
    from neatskin.errors import ConfigError
    from neatskin.tomlfile import read_toml

    data = read_toml(path, "skin profile")
    table = data.get("skin_profile")
    if not isinstance(table, dict):
        raise ConfigError(
            "no [skin_profile] table", file=str(path), field="skin_profile", fix="write it with neatskin skin fit"
        )
    channels = table.get("channel_resistance_ohm")
    if not isinstance(channels, list) or len(channels) != layout.n_channels:
        count = len(channels) if isinstance(channels, list) else "no"
        raise ConfigError(
            f"{count} channel resistances for layout '{layout.name}', which has {layout.n_channels} channels",
            file=str(path),
            field="skin_profile.channel_resistance_ohm",
            fix="fit the profile to a campaign on this layout (neatskin skin fit), or name the layout it was fitted on",
        )
    values = np.asarray(channels, float)
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ConfigError(
            "channel resistances must be positive numbers",
            file=str(path),
            field="skin_profile.channel_resistance_ohm",
            fix="refit the profile",
        )
    pinch = PinchParams(
        pinch_gain=float(table.get("pinch_gain", 1.0)), decay_ratio=float(table.get("decay_ratio", 0.5))
    )
    heights = tuple(float(h) for h in layout.channel_resistance_ohm / values)
    return SkinModel(layout, probe_radius_mm=probe_radius_mm, pinch=pinch, channel_height_factor=heights)

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
Intervals (docs/skin.md says why these): steps 1 to 3 share one cluster-robust sandwich by
position over their stacked estimating equations (`_cluster_covariance`). Each position's presses
move every estimate by a first-order influence u_c: its baselines' deviations move the drift slope
and, through the mean log baseline, the channels; its mean dR's residual moves the pinch, and so do
the channels' and the slope's own moves (the same baseline readings sit in dR = R - R_base). The
covariance is C / (C - 1) sum_c u_c u_c^T over the C positions (the slope's u_c divided by 1 - its
leverage), with Student-t quantiles on C - 1 degrees of freedom. It holds when the residuals'
spread differs from pair to pair and position to position (the log baselines' noise scales as
1 / R, dR's placement spread as the slope) and when a position's pairs move together (its placement
draws). Step 4's noise and placement intervals are a parametric bootstrap-t by position
(`fitvariance.placement_and_noise`), formed for noise^2 and s_p^2 and mapped through the square root. The
point estimates are those of the steps above; only the intervals come from here. A parameter the
data cannot separate from the others (a singular direction of J^T J) is named in a DataError, not
returned as a number.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neatskin.campaignread import read_manifest, read_presses_file
from neatskin.errors import DataError
from neatskin.layout import Layout, load_layout
from neatskin.skin.deformation import PinchParams
from neatskin.skin.fitblur import PROFILE_ROUNDS, averaged_dr, coverage_of
from neatskin.skin.fitvariance import placement_and_noise, placement_point, sum_by_cluster
from neatskin.skin.model import SkinModel
from neatskin.skin.network import equivalent_resistance

Z95 = 1.96  # the normal quantile; the intervals use Student's t on (positions - 1) degrees of freedom
MIN_POSITIONS_FOR_PINCH = 4


@dataclass(frozen=True)
class FittedValue:
    value: float
    ci95: tuple[float, float]
    coverage: float | None = None  # measured coverage of the nominal 95 % interval where it falls short (fitblur)

    def coverage_text(self) -> str:
        return "" if self.coverage is None else f" (measured coverage {100 * self.coverage:.0f} %, not 95 %)"


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
    warning: str | None = None  # the campaign's skin is one this model cannot describe (model_mismatch_warning)

    def to_toml(self) -> str:
        """A skin profile: the fitted values, each with its interval as a comment."""
        lines = [f"# skin profile fitted by `neatskin skin fit` to {self.source}"]
        if self.warning:
            lines.append(f"# warning: {self.warning}")
        lines.append("[skin_profile]")
        for name in ("pinch_gain", "decay_ratio", "placement_error_mm", "noise_ohm", "drift_per_h"):
            v = getattr(self, name)
            lines.append(f"{name} = {v.value!r}  # 95 % CI {v.ci95[0]:.4g} .. {v.ci95[1]:.4g}{v.coverage_text()}")
        lines.append(
            "channel_resistance_ohm = [" + ", ".join(f"{c.value:.6g}" for c in self.channel_resistance_ohm) + "]"
        )
        lines.append(f"pinch_correlation = {self.pinch_correlation!r}")
        return "\n".join(lines) + "\n"


def model_mismatch_warning(manifest: dict) -> str | None:
    """One line when the manifest says the campaign's skin was simulated with the finite-element pinch kernel (the
    paper-like scene's, `deformation = "fe-kernel"` or `"auto"` with that preset): the fit's model is the parametric
    pinch, which cannot describe those presses (the kernel shuts channels under the probe, a gain of about 5 there),
    so its intervals describe the parametric model's best compromise, not the skin (docs/skin.md, "Fitting a skin
    to a recorded campaign"). None for a real skin or a parametric dry run: nothing in the manifest says so."""
    from neatskin.config.scene import PRESET_DEFORMATION

    rig = manifest.get("rig")
    run = manifest.get("protocol_as_run")
    scene = run.get("scene") if isinstance(run, dict) else None
    if not (isinstance(rig, dict) and rig.get("daq") == "simulated" and isinstance(scene, dict)):
        return None
    deformation = scene.get("deformation", "auto")
    if deformation == "auto":
        deformation = PRESET_DEFORMATION.get(scene.get("preset", "ideal"), "parametric")
    if deformation != "fe-kernel":
        return None
    return (
        "this campaign's simulated skin pressed the finite-element pinch kernel, which the fit's parametric pinch "
        "cannot describe: the values and intervals below are that model's best compromise, not the skin's"
    )


def _interval(value: float, se: float, quantile: float = Z95) -> FittedValue:
    return FittedValue(float(value), (float(value - quantile * se), float(value + quantile * se)))


def _sqrt_interval(variance: float, low: float, high: float) -> FittedValue:
    """sqrt(variance) with the variance's interval (low, high) mapped through the square root (clipped at 0)."""
    return FittedValue(math.sqrt(max(variance, 0.0)), (math.sqrt(max(low, 0.0)), math.sqrt(max(high, 0.0))))


def _identified_inverse(jac: np.ndarray, names: list[str], source: str) -> np.ndarray:
    """(J^T J)^-1, or a DataError naming the parameters along a direction the data do not see."""
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
    return np.linalg.inv(jtj)


def _cluster_covariance(influence: np.ndarray) -> np.ndarray:
    """The cluster-robust covariance C / (C - 1) sum_c u_c u_c^T of per-cluster influences u_c, (C, m) -> (m, m).

    u_c is the first-order change of the estimates that cluster c's data make (their sum is the
    estimates' error); clusters are independent, observations within one need not be, nor share a
    variance (Liang and Zeger 1986; Cameron and Miller 2015, with their C / (C - 1) correction)."""
    clusters = influence.shape[0]
    return clusters / max(clusters - 1, 1) * (influence.T @ influence)


def load_campaign(folder: str | Path, manifest: dict | None = None) -> tuple[Layout, dict, dict[str, np.ndarray]]:
    """The campaign's layout, manifest and press columns (x, y, depth, press time in h, R and dR per pair).
    `manifest`: the folder's, when the caller has read it (`skin fit`'s handler); else read here."""

    folder = Path(folder)
    table = folder / "presses.parquet"
    if not table.exists():
        raise DataError(f"{folder} has no presses.parquet", field="presses.parquet", fix="fit a finished campaign")
    df = read_presses_file(table).to_pandas().sort_values("press_id")
    missing = [c for c in ("x_mm", "y_mm", "depth_mm", "position_id", "press_id") if c not in df.columns]
    if missing:
        raise DataError(
            f"{table} has no {', '.join(missing)} column: the fit needs where each press was",
            field=", ".join(missing),
            fix="fit a campaign recorded with positions (neatskin campaign run writes them)",
        )
    manifest = read_manifest(folder) if manifest is None else manifest
    layout = load_layout(folder / "inputs" / "layout.toml")
    dr = df[[c for c in df.columns if c.startswith("dR_ohm_")]].to_numpy(float)
    r = df[[c for c in df.columns if c.startswith("R_ohm_")]].to_numpy(float)
    _refuse_nonfinite(df, table)
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


def _refuse_nonfinite(df, table: Path) -> None:
    """One DataError naming every column with a NaN, an infinite position or a resistance of -inf: the fit has no
    use for them. A resistance of +inf is data, not damage: a pair cut off by a channel pinched shut (the DAQ flags
    it open circuit; `dataset validate` accepts it); fit_skin leaves such presses out and says how many."""
    columns = ["x_mm", "y_mm", "depth_mm", *(c for c in df.columns if c.startswith(("R_ohm_", "dR_ohm_")))]
    values = df[columns].to_numpy(float)
    bad = np.isnan(values) | (values == -np.inf)
    bad[:, :3] |= ~np.isfinite(values[:, :3])
    if bad.any():
        names = [c for c, b in zip(columns, bad.any(axis=0)) if b]
        ids = df["press_id"].to_numpy()[bad.any(axis=1)][:8].tolist()
        raise DataError(
            f"the fit needs finite positions and resistances that are numbers: NaN or infinite in "
            f"{', '.join(names[:5])}{f' (and {len(names) - 5} more columns)' if len(names) > 5 else ''} "
            f"(press ids {ids})",
            file=str(table),
            field=names[0],
            fix="`neatskin dataset validate` names every problem; re-press those presses or drop their rows",
        )


def fit_skin(folder: str | Path, probe_radius_mm: float = 2.75, manifest: dict | None = None) -> SkinFit:
    """Fit the skin model to the campaign in `folder` (see the module docstring). `manifest`: the folder's
    manifest, when the caller has read it (read once, not again here)."""
    from scipy.optimize import least_squares
    from scipy.special import stdtrit

    layout, manifest, c = load_campaign(folder, manifest)
    source = str(folder)
    with np.errstate(invalid="ignore"):  # a cut pair: inf - inf, left out below
        base = c["R"] - c["dR"]
    ok = np.all(np.isfinite(base), axis=1) & np.all(np.isfinite(c["dR"]), axis=1)
    if ok.sum() < 3:
        raise DataError(f"{source}: fewer than 3 presses with finite R", field="R_ohm", fix="record more presses")
    hours, base, dr = c["hours"][ok], base[ok], c["dR"][ok]
    x, y, depth, position = c["x"][ok], c["y"][ok], c["depth"][ok], c["position"][ok]
    n_presses, n_pairs = base.shape
    notes = []
    if not ok.all():
        notes.append(
            f"{int((~ok).sum())} of {ok.size} presses left out: a pair cut off (R_eq infinite, a channel pinched "
            "shut) carries no graded pinch to fit"
        )
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
    stt = float((centred_t**2).sum())
    k = float((centred_t[:, None] * centred_b).sum() / stt / n_pairs)
    resid = centred_b - k * centred_t[:, None]  # each press's log-baseline deviation, (presses, pairs)
    # 2. channel baselines from the drift-corrected mean baseline
    target = np.exp(np.mean(logb - k * hours[:, None], axis=0))

    def baseline_residual(log_r):
        return np.log(equivalent_resistance(layout, 1.0 / np.exp(log_r))) - np.log(target)

    start = np.log(layout.channel_resistance_ohm)
    sol = least_squares(baseline_residual, start, method="lm")
    names = [f"channel_resistance_ohm[{ch.name}]" for ch in layout.channels]
    jac_r = np.asarray(sol.jac)
    to_log_r = _identified_inverse(jac_r, names, source) @ jac_r.T  # d log r / d log target
    r_channels = np.exp(sol.x)
    heights = tuple(float(h) for h in layout.channel_resistance_ohm / r_channels)
    # 3. pinch from the per-position mean dR
    ids, inverse = np.unique(position, return_inverse=True)
    n_positions = len(ids)
    if n_positions < MIN_POSITIONS_FOR_PINCH:
        raise DataError(
            f"{source} pressed {n_positions} position(s): pinch_gain, decay_ratio and placement_error_mm "
            "cannot be told apart from where the presses were",
            field="pinch_gain, decay_ratio, placement_error_mm",
            fix=f"record presses at {MIN_POSITIONS_FOR_PINCH} or more positions, on and between channels",
        )
    counts = np.bincount(inverse)
    dr = dr * np.exp(-k * hours)[:, None]  # back to the resistivity at t = 0, where the baselines were fitted
    mean_dr = sum_by_cluster(inverse, dr, n_positions) / counts[:, None]
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

    blur = [0.0]  # the placement error the mean dR is averaged over (errors in variables, `fitblur`)

    def pinch_model(theta, channel_heights=heights):
        return averaged_dr(skin_for(theta, channel_heights), px, py, pd_, blur[0])

    def pinch_residual(theta, channel_heights=heights):
        model = pinch_model(theta, channel_heights)
        return np.where(np.isfinite(model), model - mean_dr, 0.0).ravel()

    def fit_pinch(start):
        return least_squares(pinch_residual, start, bounds=([0.05, 0.05], [5.0, 5.0]), x_scale=[0.1, 0.1])

    sol_p = fit_pinch([1.0, 0.5])
    for _ in range(PROFILE_ROUNDS):  # profile the placement error: s from the repeats' variance, the pinch at s
        placement_sd = placement_point(dr, inverse, counts, skin_for(sol_p.x).jacobian_mm(px, py, pd_))
        if placement_sd == blur[0]:
            break
        blur[0] = placement_sd
        sol_p = fit_pinch(sol_p.x)
    jac_p = np.asarray(sol_p.jac)
    to_theta = _identified_inverse(jac_p, ["pinch_gain", "decay_ratio"], source) @ jac_p.T  # d theta / d (-residual)
    # d residual / d log r, by forward differences (a channel's resistance up by `step` in log)
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
    # d residual / d k: the mean dR was scaled by exp(-k t) press by press
    live = np.isfinite(pinch_model(sol_p.x)).ravel()
    d_res_dk = np.where(
        live, (sum_by_cluster(inverse, hours[:, None] * dr, n_positions) / counts[:, None]).ravel(), 0.0
    )
    # each position's influence on (k, log r, theta): its presses' baseline deviations move the slope and,
    # through the mean log baseline, the channels; its mean dR's residual moves the pinch, as do the
    # channels' and the slope's own moves (the same baseline readings sit in dR = R - R_base)
    influence_k = sum_by_cluster(inverse, (centred_t * resid.sum(axis=1) / (n_pairs * stt))[:, None], n_positions)
    # a position early or late in the campaign pulls the slope more than its residuals show (its leverage
    # h_c = sum t^2 / S_tt); the leave-one-position-out change is u_c / (1 - h_c) (CR3; z std 1.04 -> 1.00)
    influence_k = influence_k / (1.0 - np.bincount(inverse, centred_t**2, n_positions) / stt)[:, None]
    influence_target = sum_by_cluster(inverse, resid / n_presses, n_positions) - influence_k * hours.mean()
    influence_r = influence_target @ to_log_r.T
    own = -(to_theta * sol_p.fun).reshape(2, n_positions, n_pairs).sum(axis=2).T
    influence_p = own - influence_r @ (to_theta @ d_res).T - influence_k * (to_theta @ d_res_dk)[None, :]
    cov = _cluster_covariance(np.hstack([influence_k, influence_r, influence_p]))
    quantile = float(stdtrit(n_positions - 1, 0.975))
    se_k = math.sqrt(cov[0, 0])
    channels = tuple(
        FittedValue(float(v), (float(v * math.exp(-quantile * s)), float(v * math.exp(quantile * s))))
        for v, s in zip(r_channels, np.sqrt(np.diag(cov)[1:-2]))
    )
    cov_p = cov[-2:, -2:]
    se_p = np.sqrt(np.diag(cov_p))
    correlation = float(cov_p[0, 1] / (se_p[0] * se_p[1]))
    # 4. placement and noise from the repeats' variance against |J|^2
    slope = skin_for(sol_p.x).jacobian_mm(px, py, pd_)  # (positions, pairs, 2)
    noise_var, placement_var = placement_and_noise(dr, inverse, counts, slope)
    noise, placement = _sqrt_interval(*noise_var), _sqrt_interval(*placement_var)
    if placement.value == 0:
        notes.append("placement_error_mm is at its bound 0: the repeats' spread does not grow with the slope")

    def stated(name: str, v: FittedValue) -> FittedValue:  # an interval that falls short says by how much
        return dataclasses.replace(v, coverage=coverage_of(name, placement.value))

    return SkinFit(
        source=source,
        channel_resistance_ohm=tuple(stated("channels", c) for c in channels),
        pinch_gain=stated("pinch_gain", _interval(sol_p.x[0], se_p[0], quantile)),
        decay_ratio=stated("decay_ratio", _interval(sol_p.x[1], se_p[1], quantile)),
        placement_error_mm=stated("placement_error_mm", placement),
        noise_ohm=stated("noise_ohm", noise),
        drift_per_h=stated("drift_per_h", _interval(k, se_k, quantile)),
        pinch_correlation=correlation,
        rms_residual_ohm=float(np.sqrt(np.mean(sol_p.fun**2))),
        notes=tuple(notes),
        warning=model_mismatch_warning(manifest),
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

"""`neatskin campaign plan`: the predicted localisation error for new positions against rig hours, before a campaign
is pressed, from simulated campaigns (`rig.simcampaign`) over campaign seeds, and an adaptive design beside it.

For each campaign size (positions x repeats at a depth) and seed: a campaign is simulated, the paper's model (or
another baseline) is fitted on all its presses, and scored on a test campaign of new positions (fresh strategy
positions, their own placement and noise), against the commanded positions, as a grouped split measures it. Rig
hours come from the G-code of the size. The adaptive design spends the first half of a size's positions at
random, fits, then puts the second half where the fitted model is worst on the skin model's noise-free presses
(where it is least certain), greedily with a spacing of a probe radius; it counts only where it reaches the
random design's error in less rig time over seeds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from neatskin.rig.protocol import CampaignProtocol
from neatskin.rig.simcampaign import (
    CampaignSize,
    Presses,
    fit_and_score,
    fitted_model,
    pair_noise_std_ohm,
    press_interval_s,
    rig_hours,
    simulate_presses,
    skin_of,
    strategy_positions,
)
from neatskin.skin.model import SkinModel

DEFAULT_SEEDS = 5
TEST_POSITIONS, TEST_REPEATS = 60, 4  # the new-position test campaign of every seed
CANDIDATES = 400  # the adaptive design's pool of strategy positions
SEED_OFFSET_TEST = 7919  # the test campaign's positions: another seed than any campaign's
PLOT_DPI = 120


@dataclass(frozen=True)
class Setting:
    """What every simulated campaign of a plan shares (picklable for joblib's processes)."""

    protocol: CampaignProtocol
    noise_std_ohm: np.ndarray
    interval_s: float
    model: str


def default_sizes(protocol: CampaignProtocol) -> list[CampaignSize]:
    """Sizes around the protocol's: positions from a quarter to twice (at least 8), repeats from a quarter (at least 2),
    and the depth +- 1 mm at its size."""
    p, r, d = protocol.press.positions.count, protocol.press.press.repeats, protocol.press.press.depth_mm
    positions = (max(8, p // 4), max(8, p // 2), p, 2 * p)
    repeats = (max(2, r // 4), max(2, r // 2), r)
    grid = {
        (positions[0], repeats[0]),
        (positions[1], repeats[0]),
        (positions[0], repeats[2]),
        (positions[2], repeats[0]),
        (positions[1], repeats[2]),
        (positions[2], repeats[1]),
        (positions[2], repeats[2]),
        (positions[3], repeats[2]),
    }
    sizes = [CampaignSize(a, b, d) for a, b in sorted(grid, key=lambda s: s[0] * s[1])]
    thickness = float(getattr(protocol.layout, "thickness_mm", d + 2.0))
    for depth in (d - 1.0, d + 1.0):
        if 0.5 <= depth <= thickness - 0.5:
            sizes.append(CampaignSize(p, r, depth))
    return sizes


def _pressed(
    setting: Setting, skin: SkinModel, xy: np.ndarray, repeats: int, depth_mm: float, seed: int, first_press: int = 0
) -> Presses:
    """A simulated campaign with the setting's noise and press interval: each of xy pressed `repeats` times."""
    return simulate_presses(
        setting.protocol,
        xy,
        repeats,
        depth_mm,
        seed,
        setting.noise_std_ohm,
        skin=skin,
        interval_s=setting.interval_s,
        first_press=first_press,
    )


def _error_on_new_positions(setting: Setting, skin: SkinModel, train: Presses, seed: int) -> float:
    """Either design's score: the setting's model fitted on train, its mean error (mm) on the seed's test campaign
    of new positions (their own seed, placement and noise) at the protocol's depth."""
    test_seed = seed + SEED_OFFSET_TEST
    xy = strategy_positions(setting.protocol, TEST_POSITIONS, test_seed)
    test = _pressed(setting, skin, xy, TEST_REPEATS, setting.protocol.press.press.depth_mm, test_seed)
    return fit_and_score(setting.model, train, test, seed)


def random_error_mm(setting: Setting, size: CampaignSize, seed: int) -> float:
    """One seed of the random design: the strategy's positions for the seed, pressed in order."""
    skin = skin_of(setting.protocol)
    xy = strategy_positions(setting.protocol, size.positions, seed)
    train = _pressed(setting, skin, xy, size.repeats, size.depth_mm, seed)
    return _error_on_new_positions(setting, skin, train, seed)


def adaptive_error_mm(setting: Setting, size: CampaignSize, seed: int) -> float:
    """One seed of the adaptive design: half the positions at random, the rest where the first fit is worst."""
    protocol, skin = setting.protocol, skin_of(setting.protocol)
    first = strategy_positions(protocol, max(2, size.positions // 2), seed)
    part1 = _pressed(setting, skin, first, size.repeats, size.depth_mm, seed)
    model = fitted_model(setting.model, part1, seed)
    pool = strategy_positions(protocol, CANDIDATES, seed + 104729)
    clean = np.asarray(skin.pair_resistance_ohm(pool[:, 0], pool[:, 1], np.full(len(pool), size.depth_mm)), float)
    clean = np.where(np.isfinite(clean), clean - skin.baseline_pair_resistance_ohm, 0.0)
    worst = np.linalg.norm(np.asarray(model.predict(clean), float) - pool, axis=1)
    chosen = _spread_choice(pool, worst, size.positions - len(first), float(protocol.press.press.probe_diameter_mm) / 2)
    part2 = _pressed(setting, skin, pool[chosen], size.repeats, size.depth_mm, seed + 1, len(part1.features))
    train = type(part1)(
        np.vstack([part1.features, part2.features]),
        np.vstack([part1.commanded_mm, part2.commanded_mm]),
        np.vstack([part1.landed_mm, part2.landed_mm]),
        np.concatenate([part1.groups, part2.groups + len(first)]),
    )
    return _error_on_new_positions(setting, skin, train, seed)


def _spread_choice(pool: np.ndarray, score: np.ndarray, count: int, spacing_mm: float) -> np.ndarray:
    """Indices of up to `count` pool points, highest score first, each at least spacing_mm from those chosen."""
    chosen: list[int] = []
    for k in np.argsort(-score):
        if len(chosen) >= count:
            break
        if not chosen or np.min(np.linalg.norm(pool[chosen] - pool[k], axis=1)) >= spacing_mm:
            chosen.append(int(k))
    return np.array(chosen, int)


def plan_campaign(
    protocol: CampaignProtocol,
    *,
    seeds: int = DEFAULT_SEEDS,
    sizes: list[CampaignSize] | None = None,
    model: str = "extra_trees",
    adaptive: bool = True,
    n_jobs: int = 2,
    progress: bool = False,
) -> pd.DataFrame:
    """One row per design and size: rig hours, presses, mean error (mm) over seeds, its std, and the seeds' errors.
    `progress`: a bar on stderr, one step per simulated campaign (design, size, seed) as it finishes."""
    from joblib import delayed
    from tqdm import tqdm

    from neatskin.orphans import watched_parallel

    sizes = default_sizes(protocol) if sizes is None else sizes
    setting = Setting(protocol, pair_noise_std_ohm(protocol), press_interval_s(protocol), model)
    depth0 = protocol.press.press.depth_mm
    jobs = [("random", s, k) for s in sizes for k in range(seeds)]
    if adaptive:
        jobs += [("adaptive", s, k) for s in sizes if s.depth_mm == depth0 and s.positions >= 8 for k in range(seeds)]
    work = {"random": random_error_mm, "adaptive": adaptive_error_mm}
    # the results in the order of `jobs` (joblib's ordered generator), each counted on the bar as it arrives: the
    # paper's plan is minutes of silence otherwise
    with tqdm(total=len(jobs), unit="campaign", desc=f"plan {protocol.name}", disable=not progress) as bar:
        errors = []
        for error in watched_parallel(n_jobs, return_as="generator")(
            delayed(work[d])(setting, s, k) for d, s, k in jobs
        ):
            errors.append(error)
            bar.update(1)
    hours = {s: rig_hours(protocol, s) for s in sizes}
    rows = []
    for design in ("random", "adaptive"):
        for s in sizes:
            got = [e for (d, z, _), e in zip(jobs, errors, strict=True) if d == design and z == s]
            if not got:
                continue
            rows.append(
                {
                    "design": design,
                    "positions": s.positions,
                    "repeats": s.repeats,
                    "depth_mm": s.depth_mm,
                    "presses": s.presses,
                    "rig_hours": hours[s],
                    "mean_error_mm": float(np.mean(got)),
                    "std_error_mm": float(np.std(got, ddof=1)) if len(got) > 1 else 0.0,
                    "seeds": len(got),
                    "errors_mm": [float(e) for e in got],
                }
            )
    return pd.DataFrame(rows)


def pareto_frontier(hours: np.ndarray, error_mm: np.ndarray) -> np.ndarray:
    """Indices of the sizes no other size dominates (as few or fewer hours and as low or lower error, one of them
    strictly), in rising hours; along them the error falls strictly. A dominated size (25 x 28: 1.51 h for 4.22 mm
    beside 50 x 7's 0.76 h for 3.16 mm) says nothing about what the rig time buys, so it is left out; of equal
    points the first is kept."""
    order = np.lexsort((error_mm, hours))  # by hours, ties by error: the first of a tie is the better
    kept: list[int] = []
    for k in order:
        if not kept or error_mm[k] < error_mm[kept[-1]]:
            kept.append(int(k))
    return np.array(kept, int)


def hours_for_error(frame: pd.DataFrame, target_mm: float, design: str = "random") -> float | None:
    """Rig hours the design needs for target_mm at the protocol's depth: along the Pareto frontier of its sizes
    (`pareto_frontier`), interpolated between the two frontier neighbours whose errors bracket the target, linearly
    in log hours (the sizes double from one to the next and the error falls about as a power of the presses, so
    log hours is the axis it is smooth on; the plot's axis too); the first frontier size's hours when it already
    reaches the target; None when no size reaches it."""
    rows = frame[frame["design"] == design]
    if rows.empty:
        return None
    rows = rows[rows["depth_mm"] == rows["depth_mm"].mode().iloc[0]]
    all_hours, all_error = rows["rig_hours"].to_numpy(float), rows["mean_error_mm"].to_numpy(float)
    front = pareto_frontier(all_hours, all_error)
    hours, error = all_hours[front], all_error[front]
    if error[-1] > target_mm:
        return None
    k = int(np.argmax(error <= target_mm))
    if k == 0:
        return float(hours[0])
    lo, hi = np.log(hours[k - 1]), np.log(hours[k])
    share = (error[k - 1] - target_mm) / (error[k - 1] - error[k])  # > 0: the frontier's error falls strictly
    return float(np.exp(lo + share * (hi - lo)))


def adaptive_verdict(frame: pd.DataFrame) -> list[str]:
    """Per size, whether the adaptive design reaches the random design's error in less rig time over seeds: its
    mean error with its 95 % band (paired over seeds) against the random design at the same size."""
    lines = []
    random = frame[frame["design"] == "random"]
    adaptive: list[Any] = list(frame[frame["design"] == "adaptive"].itertuples(index=False))
    for row in adaptive:
        same = random[
            (random["positions"] == row.positions)
            & (random["repeats"] == row.repeats)
            & (random["depth_mm"] == row.depth_mm)
        ].iloc[0]
        diff = np.asarray(row.errors_mm) - np.asarray(same["errors_mm"])
        t = float(stats.t.ppf(0.975, len(diff) - 1)) if len(diff) > 1 else np.inf
        half = t * diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else np.inf
        needed = hours_for_error(frame, float(row.mean_error_mm))
        if diff.mean() + half < 0:
            verdict = "a result: lower error at the same rig time over seeds"
            if needed is not None and needed > row.rig_hours:
                verdict += f"; random needs {needed:.2f} h for it ({needed / row.rig_hours:.2f}x)"
        elif diff.mean() - half > 0:
            verdict = "worse than random over seeds"
        else:
            verdict = "no result: within the seeds' spread of random"
        lines.append(
            f"{row.positions} x {row.repeats}: adaptive {row.mean_error_mm:.2f} mm against random "
            f"{same['mean_error_mm']:.2f} mm at {row.rig_hours:.2f} h, paired difference "
            f"{diff.mean():+.2f} +- {half:.2f} mm (95 %): {verdict}"
        )
    return lines


def format_plan(frame: pd.DataFrame, protocol_name: str, paper_hours: float | None = None) -> str:
    """The terminal table: rig hours, presses, mean error in mm and its spread over seeds, per design and size."""
    lines = [
        f"campaign plan for {protocol_name}: error for new positions against rig time "
        f"(mean +- std over {int(frame['seeds'].max())} campaign seeds)",
        f"{'design':<9} {'positions':>9} {'repeats':>7} {'depth mm':>8} {'presses':>7} {'rig h':>7} "
        f"{'mean error mm':>13} {'spread mm':>9}",
    ]
    lines.append("-" * len(lines[-1]))
    rows: list[Any] = list(frame.itertuples(index=False))
    for row in rows:
        mark = "  <- the protocol" if paper_hours is not None and abs(row.rig_hours - paper_hours) < 1e-9 else ""
        lines.append(
            f"{row.design:<9} {row.positions:>9} {row.repeats:>7} {row.depth_mm:>8.2f} {row.presses:>7} "
            f"{row.rig_hours:>7.2f} {row.mean_error_mm:>13.2f} {row.std_error_mm:>9.2f}{mark}"
        )
    return "\n".join(lines)


def plot_plan(frame: pd.DataFrame, path: Path, protocol_hours: float | None = None) -> Path:
    """plan_figure written as a PNG."""
    import matplotlib.pyplot as plt

    fig = plan_figure(frame, protocol_hours)
    fig.savefig(path, dpi=PLOT_DPI)
    plt.close(fig)
    return path


def plan_figure(frame: pd.DataFrame, protocol_hours: float | None = None) -> Any:
    """Error against rig hours per design (the protocol's depth), std over seeds as error bars; depth variants as
    separate markers; the protocol's own size marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=PLOT_DPI)  # laid out at the dpi it is written at
    depth0 = frame.loc[frame["design"] == "random", "depth_mm"].mode().iloc[0]
    repeats0 = frame.loc[frame["design"] == "random", "repeats"].max()
    for design, color, shift in (("random", "C0", 0.97), ("adaptive", "C1", 1.03)):
        rows = frame[(frame["design"] == design) & (frame["depth_mm"] == depth0)].sort_values("rig_hours")
        if rows.empty:
            continue
        ax.errorbar(
            rows["rig_hours"] * shift,
            rows["mean_error_mm"],
            yerr=rows["std_error_mm"],
            marker="o",
            capsize=3,
            color=color,
            linestyle="none",
            label=f"{design} positions, {depth0:g} mm deep",
        )
        line = rows[rows["repeats"] == repeats0]
        ax.plot(line["rig_hours"] * shift, line["mean_error_mm"], color=color, alpha=0.6)
        if design == "random":
            for row in rows.itertuples(index=False):
                ax.annotate(
                    f"{row.positions}x{row.repeats}",
                    (row.rig_hours, row.mean_error_mm),
                    fontsize=6,
                    xytext=(4, 4),
                    textcoords="offset points",
                    color="0.3",
                )
    other = frame[(frame["design"] == "random") & (frame["depth_mm"] != depth0)]
    for k, row in enumerate(other.itertuples(index=False)):
        ax.errorbar(
            [row.rig_hours],
            [row.mean_error_mm],
            yerr=[row.std_error_mm],
            marker="s",
            capsize=3,
            linestyle="none",
            color=f"C{2 + k}",
            label=f"random {row.positions}x{row.repeats} at {row.depth_mm:g} mm",
        )
    if protocol_hours is not None:
        ax.axvline(protocol_hours, color="0.5", linestyle=":", label=f"the protocol: {protocol_hours:.2f} h")
    ax.set_xscale("log")
    ax.set_xlabel("rig hours (G-code time)")
    ax.set_ylabel("mean error for new positions, mm")
    # two lines: on one, the title was wider than the figure and cut on the right
    ax.set_title(
        f"Predicted error against rig time (simulated campaigns)\nline: {repeats0} repeats; mean +- std over seeds",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig

"""The floors of a report, read from physical_limit.parquet: the label-noise floor per split, the landing-point bound,
each model's excess over its split's floor, report.md's section that names them, and which RMS / bound ratios the
full table can show.

`neatskin.baselines.floors` says what each floor measures; this module pools them over the positions and puts
them beside the results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from neatskin.baselines.floors import SPLIT_PRIOR, split_floor_column

SECTION = "## Floors: label-noise floor and landing-point bound"
SPLIT_NAMES = {"new_positions": "new positions (grouped split)", "by_row": "split by row (random, design)"}


@dataclass(frozen=True)
class Floors:
    """Pooled over positions: the label-noise floor per prior ("new_positions", "by_row") as (mean, RMS) in mm,
    and the landing-point bound as sqrt(mean bound^2)."""

    label_mm: dict[str, tuple[float, float]]
    landing_rms_mm: float
    landing_known_skin_rms_mm: float | None = None
    # the landing-point bound's `bound_spread_mm` (median, positions beyond the probe radius, positions), this skin's
    # fabrication unknown and known, and how many positions it is infinite at: what the pooled RMS hides when a few
    # positions hold it
    landing_spread: tuple[float, int, int] = (np.nan, 0, 0)
    landing_known_skin_spread: tuple[float, int, int] | None = None
    landing_infinite: int = 0
    # its median over the positions where it is finite: the median above counts the infinite ones, which lifts it
    landing_finite_median_mm: float = np.nan

    def of_split(self, split: str) -> tuple[float, float]:
        return self.label_mm[SPLIT_PRIOR.get(split, "by_row")]


def bound_spread_mm(
    limit: pd.DataFrame | None, column: str = "crb_mm", radius_mm: float = 2.75
) -> tuple[float, int, int] | None:
    """(the median over positions of a bound, at how many positions it exceeds the probe radius, how many positions
    there are): what the skin measures at a typical position and where it does not locate a press within its own
    footprint, for planning where the pooled RMS is infinite or held by a few positions (on the FE skin a press
    that shuts every channel it reaches, around a junction, tells which channels, not where among them: its bound is
    infinite or huge). None when
    the limit or its column is absent."""
    if limit is None or len(limit) == 0 or column not in limit.columns:
        return None
    crb = limit[column].to_numpy(dtype=float)
    return float(np.median(crb)), int(np.count_nonzero(crb > radius_mm)), int(crb.size)


def comparable(limit: pd.DataFrame | None, column: str, extent_mm: float) -> bool:
    """Whether a pooled bound is compared with the errors: finite and within the skin's extent at every position.
    Where a position's bound exceeds the skin itself (infinite, or huge beside such a spot: a press that
    shuts every channel it reaches tells which channels, not where among them), no estimator that answers on the skin is
    unbiased there, so the bound (of unbiased estimators) says nothing, and it holds the pooled RMS."""
    if limit is None or len(limit) == 0 or column not in limit.columns:
        return False
    return bool(np.all(limit[column].to_numpy(dtype=float) <= extent_mm))


def skin_extent_mm(layout, positions_mm: np.ndarray) -> float:
    """The skin's larger side (the layout's bounds), or the pressed positions' larger spread without a layout."""
    if layout is not None:
        x0, y0, x1, y1 = layout.bounds_mm
        return float(max(x1 - x0, y1 - y0))
    return float(np.max(np.ptp(np.asarray(positions_mm, float), axis=0))) if len(positions_mm) else np.inf


def read_floors(limit: pd.DataFrame | None, radius_mm: float = 2.75) -> Floors | None:
    """The pooled floors of a physical limit frame (radius_mm: the probe's, for `Floors.landing_spread`); None when
    it predates them (no `landing_bound_mm`)."""
    if limit is None or len(limit) == 0 or "landing_bound_mm" not in limit.columns:
        return None
    label = {}
    for prior in ("new_positions", "by_row"):
        mean = limit[f"label_floor_{prior}_mean_mm"].to_numpy(float)
        rms = limit[f"label_floor_{prior}_rms_mm"].to_numpy(float)
        label[prior] = (float(np.mean(mean)), float(np.sqrt(np.mean(rms**2))))
    landing = limit["landing_bound_mm"].to_numpy(float)
    known = None
    if "landing_bound_known_skin_mm" in limit.columns:
        known = float(np.sqrt(np.mean(limit["landing_bound_known_skin_mm"].to_numpy(float) ** 2)))
    spread = bound_spread_mm(limit, "landing_bound_mm", radius_mm)
    assert spread is not None  # the column is there (checked above)
    return Floors(
        label,
        float(np.sqrt(np.mean(landing**2))),
        known,
        spread,
        bound_spread_mm(limit, "landing_bound_known_skin_mm", radius_mm),
        int(np.count_nonzero(np.isinf(landing))),
        float(np.median(landing[np.isfinite(landing)])) if np.isfinite(landing).any() else np.nan,
    )


def add_floor_columns(table: pd.DataFrame, floors: Floors | None) -> pd.DataFrame:
    """label_floor_mean_mm / label_floor_rms_mm of each row's split, excess_mean_mm (mean error - floor mean),
    excess_rms_mm, landing_bound_rms_mm."""
    if floors is None or table.empty:
        return table
    table = table.copy()
    per = [floors.of_split(str(s)) for s in table["split"]]
    table["label_floor_mean_mm"] = [m for m, _ in per]
    table["label_floor_rms_mm"] = [r for _, r in per]
    table["excess_mean_mm"] = table["mean_error_mm"] - table["label_floor_mean_mm"]
    table["excess_rms_mm"] = table["rms_error_mm"] - table["label_floor_rms_mm"]
    table["landing_bound_rms_mm"] = floors.landing_rms_mm
    return table


def below_label_floor(table: pd.DataFrame) -> pd.Series:
    """Rows whose RMS error is below the label-noise floor (RMS) of their own split."""
    if "label_floor_rms_mm" not in table.columns:
        return pd.Series(False, index=table.index)
    floor = table["label_floor_rms_mm"].to_numpy(float)
    return pd.Series((table["rms_error_mm"].to_numpy(float) < floor) & (floor > 0), index=table.index)


def floors_section(table: pd.DataFrame, floors: Floors | None, campaign_seeds: int = 1) -> list[str]:
    """report.md's section: both floors by name, per split, and each model's excess over its split's floor."""
    if floors is None:
        return []
    lines = [
        SECTION,
        "",
        "| floor | what it measures | mean mm | RMS mm |",
        "|---|---|---:|---:|",
    ]
    for prior, name in SPLIT_NAMES.items():
        mean, rms = floors.label_mm[prior]
        lines.append(
            f"| label-noise floor, {name} | Bayes error against the commanded positions the labels hold, under the "
            f"scene's placement error, landing point known | {mean:.3g} | {rms:.3g} |"
        )
    lines += [
        f"| landing-point bound | Cramér-Rao bound on where a press landed from its 28 dR: electronics noise, depth "
        f"jitter, fluid drift and fabrication spread (per press) as nuisances | | {_pooled(floors.landing_rms_mm)} |",
    ]
    if floors.landing_known_skin_rms_mm is not None:
        lines.append(
            "| landing-point bound, this skin's fabrication known | the same for a model trained on this skin, "
            f"which has seen its channels | | {_pooled(floors.landing_known_skin_rms_mm)} |"
        )
    median, beyond, positions = floors.landing_spread
    if beyond:
        known = floors.landing_known_skin_spread
        known_text = "" if known is None else f" ({known[0]:.3g} mm with this skin's fabrication known)"
        lines += [
            "",
            f"The landing-point bound exceeds the probe radius at {beyond} of {positions} positions (infinite at "
            f"{floors.landing_infinite}: a press that shuts every channel it reaches, around a junction, tells which "
            f"channels, not where among them); its median over all {positions} positions is {median:.3g} mm{known_text}"
            + (
                f", over the {positions - floors.landing_infinite} where it is finite "
                f"{floors.landing_finite_median_mm:.3g} mm."
                if floors.landing_infinite and np.isfinite(floors.landing_finite_median_mm)
                else "."
            ),
        ]
    lines += [
        "",
        "The label-noise floor is computed (Monte Carlo over landing points, `neatskin.baselines.floors`), not "
        "assumed: for new positions the prior over where a press was commanded is the protocol's position strategy, "
        "for a split by row it is the campaign's own positions, which a model can snap to. No model that sees one "
        "press can beat the floor of its split; one that does (RMS below it) is flagged as memorisation: it uses "
        "something beyond the press, e.g. the campaign's time order. The landing-point bound says what the skin "
        "and electronics measure; the labels, not the skin, set the floor when it is far below the label floor.",
        "",
    ]
    if {"label_floor_mean_mm", "excess_mean_mm"} <= set(table.columns):
        lines += ["| model | split | mean error mm | its split's floor (mean) mm | excess mm | RMS excess mm |"]
        lines += ["|---|---|---:|---:|---:|---:|"]
        for row in table.itertuples(index=False):
            lines.append(
                f"| {row.model} | {row.split} | {row.mean_error_mm:.3g} | {row.label_floor_mean_mm:.3g} "
                f"| {row.excess_mean_mm:+.3g} | {row.excess_rms_mm:+.3g} |"
            )
        lines.append("")
    lines += [
        f"Every interval in this report covers networks and splits of this one campaign ({campaign_seeds} campaign "
        "seed); it does not cover the campaign draw (positions, placement and noise). "
        "`benchmarks/paper_dry_runs.py` gives the spread over campaign seeds from full main jobs (the README's "
        "figures), `benchmarks/bench_paper_seeds.py` from the faster simulated campaigns of `campaign plan`.",
        "",
    ]
    return lines


RATIO_COLUMNS = (("rms_over_crb", "RMS / bound"), ("rms_over_crb_nuisance", "RMS / nuisance bound"))
RATIO_BOUNDS = {
    "rms_over_crb": ("crb_mm", "electronics-only bound"),
    "rms_over_crb_nuisance": ("crb_nuisance_mm", "bound with nuisances"),
}


def uncompared_ratios(table: pd.DataFrame) -> list[str]:
    """The ratio columns of the table that no result has (NaN in every row: its bound is compared with nothing)."""
    return [c for c, _ in RATIO_COLUMNS if c in table.columns and not np.isfinite(table[c].to_numpy(float)).any()]


def ratio_note(table: pd.DataFrame, limit: pd.DataFrame | None, extent_mm: float = np.inf) -> str:
    """One line for the full table: which RMS / bound columns it has, and for a bound with no column why nothing is
    compared with it (its pooled value is infinite, or held by positions beyond the skin)."""
    shown = [h for c, h in RATIO_COLUMNS if c in table.columns and c not in uncompared_ratios(table)]
    text = ""
    if "RMS / bound" in shown:
        text += " `RMS / bound` = RMS error over the pooled electronics-only bound."
    if "RMS / nuisance bound" in shown:
        text += " `RMS / nuisance bound` = RMS error over the pooled bound with nuisances."
    for column in uncompared_ratios(table):
        bound_column, name = RATIO_BOUNDS[column]
        values = None if limit is None or bound_column not in limit.columns else limit[bound_column].to_numpy(float)
        if values is None:
            why = "the dataset has no such bound"
        else:
            infinite = int(np.count_nonzero(np.isinf(values)))
            beyond = int(np.count_nonzero(np.isfinite(values) & (values > extent_mm)))
            parts = [f"infinite at {infinite} of {values.size} positions (unresolvable: a channel the probe shuts)"]
            parts = parts if infinite else []
            parts += [f"beyond the skin ({extent_mm:g} mm) at {beyond} of {values.size}"] if beyond else []
            why = f"it is {' and '.join(parts) or 'not compared'}, so its pooled value says nothing"
        text += f" No result is compared with the {name} (no column for it): {why}."
    return text


def _pooled(rms_mm: float) -> str:
    """A pooled landing bound's cell: the figure, or why there is none (an infinite RMS is no error size)."""
    return f"{rms_mm:.3g}" if np.isfinite(rms_mm) else "inf: infinite where a channel is shut, median below"


def floor_column(split: str, stat: str = "rms") -> str:
    """The physical_limit.parquet column behind a split's floor (for readers who want it per position)."""
    return split_floor_column(split, stat)

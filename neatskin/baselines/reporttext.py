"""The text of report.md: warnings first, the paper beside the same protocol on the simulated skin, then the full table.

Nothing is bold unless its 95 % interval of the mean error lies wholly below every other
model's interval on the same split.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.baselines.dataset import PHYSICAL_LIMIT_NAME, BaselineData
from neatskin.baselines.evaluate import DESIGN_POSITIONS, DESIGN_PRESSES, PAPER_FRACTIONS

SPLIT_TEXT = {
    "grouped": "k-fold over positions: no test position is in training. The honest error for a press at a "
    "position never pressed before.",
    "random": "the paper's split by row, {t} % train / {v} % validation / {s} % test, a fresh split per repeat. "
    "Repeats of a test position are in training, so this error is optimistic for new positions.",
    "design": f"the paper's Fig. 9 test design: {DESIGN_POSITIONS} positions x {DESIGN_PRESSES} presses held out "
    "per repeat (their other presses stay in training, as in a split by row), so every test position has "
    f"{DESIGN_PRESSES} predictions and an ellipse.",
}


def bold_winners(table: pd.DataFrame) -> set[tuple[str, str]]:
    """(model, split) whose 95 % interval of the mean error is wholly below every other model's on its split."""
    winners = set()
    for split, rows in table.groupby("split", sort=False):
        for row in rows.itertuples(index=False):
            if row.below_bound:  # memorisation is no result to celebrate
                continue
            others = rows[(rows["model"] != row.model) & ~rows["below_bound"]]  # memorisation is no competitor
            if len(others) and (row.mean_error_mm_hi < others["mean_error_mm_lo"]).all():
                winners.add((str(row.model), str(split)))
    return winners


def _cell(row, key: str, fmt: str = ".3g", scale: str = "") -> str:
    mean, std = getattr(row, key), getattr(row, f"{key}_std")
    lo, hi = getattr(row, f"{key}_lo"), getattr(row, f"{key}_hi")
    return f"{mean:{fmt}}{scale} ± {std:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def markdown_table(table: pd.DataFrame) -> list[str]:
    """The full results as a markdown table: mean ± std over repeats [95 % interval of the mean]."""
    winners = bold_winners(table)
    lines = [
        "| model | split | repeats | test rows | mean error mm | median mm | RMS mm | MSE mm² | MSE/coord mm² "
        "| within probe % | failures % | fit s | predict µs/press | flag |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in table.itertuples(index=False):
        mean = _cell(row, "mean_error_mm")
        if (row.model, row.split) in winners:
            mean = f"**{mean}**"
        flag = "memorisation: below the bound" if row.below_bound else ""
        lines.append(
            f"| {row.model} | {row.split} | {row.n_repeats} | {row.n_test} | {mean} | {_cell(row, 'median_error_mm')} "
            f"| {_cell(row, 'rms_error_mm')} | {_cell(row, 'mse_mm2')} | {_cell(row, 'mse_per_coordinate_mm2')} "
            f"| {_cell(row, 'within_probe_pct', '.1f')} | {_cell(row, 'failure_pct', '.1f')} | {row.fit_time_s:.3g} "
            f"| {row.predict_time_per_sample_us:.3g} | {flag} |"
        )
    return lines


def _like_for_like(table: pd.DataFrame, paper: Mapping[str, float], data: BaselineData) -> list[str]:
    lines = [
        "## The paper beside the same protocol on the simulated skin",
        "",
        "| | skin | split | networks | mean error mm | within probe % | MSE/coord mm² |",
        "|---|---|---|---|---|---|---|",
        f"| paper (Judd et al.) | real | random 95/3/2 | 10 | {paper['mean_error_mm']} ± {paper['std_error_mm']} "
        f"(as reported) | {paper['within_probe_pct']:.0f} | {paper['mse_mm2']} (as reported; likely this convention) |",
    ]
    lm = table[(table["model"] == "lm_network") & (table["split"] == "random")]
    for row in lm.itertuples(index=False):
        lines.append(
            f"| this dataset, same protocol | simulated (`{data.skin_fidelity or 'unknown'}`) | random 95/3/2 "
            f"| {row.n_repeats} | {_cell(row, 'mean_error_mm')} | {_cell(row, 'within_probe_pct', '.1f')} "
            f"| {_cell(row, 'mse_per_coordinate_mm2')} |"
        )
    if lm.empty:
        lines.append("| this dataset | | random split not run (`--split both` runs it) | | | | |")
    lines += [
        "",
        "Each of our networks is one repeat: a fresh 95/3/2 split, one LM network stopped and chosen on its "
        "validation rows, scored on its test rows; ± is the std over the networks and [ ] the 95 % interval of "
        "their mean. The paper's ± is as it reports it. The skins differ (real against simulated), so this row "
        "compares the method, not the skins.",
        "",
    ]
    grouped = table[(table["model"] == "lm_network") & (table["split"] == "grouped")]
    for row in grouped.itertuples(index=False):
        lines += [
            "### New positions (grouped split)",
            "",
            f"The LM network: mean error {_cell(row, 'mean_error_mm')} mm, "
            f"{_cell(row, 'within_probe_pct', '.1f')} % within the probe radius. This is a different question from "
            "the paper's: the press lands at a position the network never saw. It has no counterpart in the paper.",
            "",
        ]
    return lines


def _bound_text(bound: float, nuisance_bound: float | None, table: pd.DataFrame) -> list[str]:
    """The physical limit: the electronics-only bound (the memorisation flag) beside the bound with nuisances."""
    lines = [
        f"## Physical limit (`{PHYSICAL_LIMIT_NAME}`)",
        "",
        "| bound on the RMS position error, pooled as sqrt(mean CRB²) over positions | mm |",
        "|---|---:|",
        f"| electronics only (`crb_mm`): depth, fluid drift and landing point known | {bound:.3g} |",
    ]
    if nuisance_bound is not None:
        lines.append(
            f"| with the scene's press depth jitter, fluid drift and placement error as nuisances "
            f"(`crb_nuisance_mm`; priors in the file's metadata) | {nuisance_bound:.3g} |"
        )
    lines += [
        "",
        "Both are Cramér-Rao bounds on the RMS error of any unbiased estimator of a press's position from its "
        "28 dR with the dry run's per-pair noise. A result below the electronics-only bound (RMS error below it, "
        "or median error below half of it) is flagged as memorisation: it can only come from memorising training "
        "positions (a split by row).",
    ]
    if nuisance_bound is not None:
        lines += [
            "",
            "The bound with nuisances is the one a learned model faces on a paper-like skin: each press lands "
            "off its commanded position and at its own depth, in a fluid that drifts, and the labels hold the "
            "commanded position. A model cannot beat it on average for presses at new positions (the grouped "
            "split); on a split by row a model may still go below it only by snapping to the grid of training "
            "positions, a bias the bound does not cover, which is memorisation too. With no nuisance in the "
            "scene (the `ideal` preset) the two bounds are equal. `RMS/CRBn` in the terminal table is the RMS "
            "error over this bound.",
        ]
        if "rms_over_crb_nuisance" in table.columns:
            k = int(np.argmin(table["rms_over_crb_nuisance"].to_numpy(float)))
            model, split, ratio = table["model"].iloc[k], table["split"].iloc[k], table["rms_over_crb_nuisance"].iloc[k]
            lines += [
                "",
                f"Closest to it: `{model}` ({split}) at {ratio:.3g} times the bound with nuisances.",
            ]
    return [*lines, ""]


def markdown_report(
    *,
    data: BaselineData,
    table: pd.DataFrame,
    bound: float | None,
    splits: Sequence[str],
    nuisance_bound: float | None = None,
    files: Mapping[str, Path],
    random_state: int | None,
    notes: Sequence[str],
    n_jobs: int,
    elapsed_s: float,
    descriptions: Mapping[str, str],
    paper: Mapping[str, float],
    lm_restarts: int | None,
) -> str:
    t, v, s = (int(100 * f) for f in PAPER_FRACTIONS)
    lines = ["# Baseline report", ""]
    if notes:
        lines += ["## Warnings", "", *[f"- {n}" for n in notes], ""]
    lines += [
        f"Dataset: `{data.source}`: {len(data.y)} presses at {len(np.unique(data.groups))} positions, "
        f"{data.X.shape[1]} pair features; {data.n_flagged_dropped} flagged presses dropped, "
        f"{data.n_saturated} kept with a cut pair's dR saturated. Seeds from "
        f"{random_state}; fits in {n_jobs if n_jobs > 0 else 'all'} process(es); report made in {elapsed_s:.1f} s.",
        "",
        *_like_for_like(table, paper, data),
        "## All models and splits",
        "",
        "Splits:",
        *[f"- `{name}`: {SPLIT_TEXT[name].format(t=t, v=v, s=s)}" for name in splits],
        "",
        "Each cell: mean ± std over the repeats [95 % Student-t interval of the mean]. Errors are Euclidean (mm); "
        "RMS = sqrt(MSE); `MSE mm²` = mean of dx²+dy²; `MSE/coord` = MATLAB's `mse` over both coordinates (half of "
        "it); `within probe` = share within the 2.75 mm probe radius; `failures` = share more than 3 probe radii "
        "off. Fit s: mean per fit. A mean error is bold only when its interval lies below every other model's "
        "on its split.",
        "",
        *markdown_table(table),
        "",
    ]
    if bound is not None:
        lines += _bound_text(bound, nuisance_bound, table)
    lm_note = (
        f"The LM network trains {lm_restarts} network(s) per repeat (best on validation)."
        if lm_restarts is not None
        else "The LM network keeps its default restarts."
    )
    lines += [
        "Models (`inversion` needs no training data: its fit time is 0 and its cost is in predict time):",
        *[f"- `{name}`: {text}" for name, text in descriptions.items()],
        "",
        lm_note,
        "",
        "Files:",
        *[f"- {label}: `{path.name}`" for label, path in files.items()],
        "",
    ]
    return "\n".join(lines)

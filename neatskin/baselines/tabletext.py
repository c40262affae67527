"""The report's tables as markdown: every figure to 3 significant figures, mean ± std [95 % interval] cells,
the bold winners and the flag column; the compact table and the full one.

Nothing is bold unless its 95 % interval of the mean error lies wholly below every other
model's interval on the same split. `reporttext` writes report.md around these tables.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from neatskin.baselines.floortext import RATIO_COLUMNS, uncompared_ratios


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


def sig3(value: Any) -> str:
    """A number to 3 significant figures, never in scientific notation: 2.00, 0.162, 43,400, 0.00443; nan and
    inf as such. One rule for every cell, so a column reads at one precision."""
    x = float(value)
    if not np.isfinite(x):
        return "nan" if np.isnan(x) else ("inf" if x > 0 else "-inf")
    if x == 0:
        return "0"
    decimals = 2 - int(np.floor(np.log10(abs(x))))
    rounded = round(x, decimals)
    if rounded != 0 and int(np.floor(np.log10(abs(rounded)))) > int(np.floor(np.log10(abs(x)))):  # 9.996 -> 10.0
        decimals -= 1
        rounded = round(x, decimals)
    return f"{rounded:,.{max(decimals, 0)}f}"


def cell_text(row, key: str) -> str:
    """mean ± std [95 % interval of the mean], each to 3 significant figures."""
    mean, std = getattr(row, key), getattr(row, f"{key}_std")
    lo, hi = getattr(row, f"{key}_lo"), getattr(row, f"{key}_hi")
    return f"{sig3(mean)} ± {sig3(std)} [{sig3(lo)}, {sig3(hi)}]"


def _interval(row, key: str) -> str:
    """mean [95 % interval of the mean]: the compact table's cell."""
    return f"{sig3(getattr(row, key))} [{sig3(getattr(row, f'{key}_lo'))}, {sig3(getattr(row, f'{key}_hi'))}]"


NUISANCE_NOTE = "below the nuisance bound"


def flag_text(row) -> str:
    """The flag column: memorisation (below the electronics-only bound, the one flag) or, as a note that is not
    a flag, an RMS error under the bound with nuisances (possible on a split by row only; see the bound text)."""
    if row.below_bound:
        return "memorisation: below the bound"
    ratio = getattr(row, "rms_over_crb_nuisance", None)
    if ratio is not None and np.isfinite(ratio) and ratio < 1:
        return f"{NUISANCE_NOTE} ({sig3(ratio)}×)"
    return ""


def main_table(table: pd.DataFrame) -> list[str]:
    """The compact table at the head of the results: mean error with its 95 % interval, RMS, share within the
    probe radius, time, flag. Every figure to 3 significant figures."""
    winners = bold_winners(table)
    lines = [
        "| model | split | mean error mm [95 % CI] | RMS mm | within probe % | fit s | predict µs/press | flag |",
        "|---|---|---|---:|---:|---:|---:|---|",
    ]
    for row in table.itertuples(index=False):
        mean = _interval(row, "mean_error_mm")
        if (row.model, row.split) in winners:
            mean = f"**{mean}**"
        lines.append(
            f"| {row.model} | {row.split} | {mean} | {sig3(row.rms_error_mm)} | {sig3(row.within_probe_pct)} "
            f"| {sig3(row.fit_time_s)} | {sig3(row.predict_time_per_sample_us)} | {flag_text(row)} |"
        )
    return lines


def markdown_table(table: pd.DataFrame) -> list[str]:
    """The full results as a markdown table: mean ± std over repeats [95 % interval of the mean], and the RMS
    error over each bound some result is compared with (a column NaN in every row is left out: `ratio_note`
    says why)."""
    winners = bold_winners(table)
    ratios = [(c, h) for c, h in RATIO_COLUMNS if c in table.columns and c not in uncompared_ratios(table)]
    head = (
        "| model | split | repeats | test rows | mean error mm | median mm | RMS mm | MSE mm² | MSE/coord mm² "
        "| within probe % | failures % | fit s | predict µs/press |"
    )
    head += "".join(f" {h} |" for _, h in ratios) + " flag |"
    lines = [head, "|" + "---|" * (14 + len(ratios))]
    for row in table.itertuples(index=False):
        mean = cell_text(row, "mean_error_mm")
        if (row.model, row.split) in winners:
            mean = f"**{mean}**"
        ratio_cells = "".join(f" {sig3(getattr(row, c))} |" for c, _ in ratios)
        lines.append(
            f"| {row.model} | {row.split} | {row.n_repeats} | {row.n_test} | {mean} | {cell_text(row, 'median_error_mm')} "
            f"| {cell_text(row, 'rms_error_mm')} | {cell_text(row, 'mse_mm2')} | {cell_text(row, 'mse_per_coordinate_mm2')} "
            f"| {cell_text(row, 'within_probe_pct')} | {cell_text(row, 'failure_pct')} | {sig3(row.fit_time_s)} "
            f"| {sig3(row.predict_time_per_sample_us)} |{ratio_cells} {flag_text(row)} |"
        )
    return lines

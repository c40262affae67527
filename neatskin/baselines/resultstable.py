"""The results table: one row per model and split, its ratios to the physical bounds, the memorisation flag, and
the warnings the results raise.

Pure functions of the results, the dataset and physical_limit.parquet's bounds and floors; `report.run_baselines`
builds the table with them, writes it and hands it to the text (`reporttext`) and the plots.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
import pandas as pd

from neatskin.baselines.dataset import BaselineData
from neatskin.baselines.evaluate import ModelResult
from neatskin.baselines.floortext import Floors, add_floor_columns, below_label_floor

MEDIAN_BOUND_SHARE = 0.5  # see results_table

BOUND_COLUMNS = ("crb_mm", "crb_nuisance_mm")  # the physical limit's bounds on the position error, in the report


def bound_rms_mm(limit: pd.DataFrame | None, column: str = "crb_mm") -> float | None:
    """Pooled RMS bound sqrt(mean crb^2) over the positions (inf if any position is unobservable); None when the
    limit or its column is absent (`crb_nuisance_mm` is missing from datasets written before it existed)."""
    if limit is None or len(limit) == 0 or column not in limit.columns:
        return None
    crb = limit[column].to_numpy(dtype=float)
    return float(np.sqrt(np.mean(crb * crb)))


def _ratio(rms_mm: pd.Series, bound_mm: float, compared: bool | None) -> pd.Series | float:
    if bound_mm == 0:
        return np.inf
    return rms_mm / bound_mm if compared is not False and np.isfinite(bound_mm) else np.nan


def results_table(
    results: Iterable[ModelResult],
    bound: float | None,
    nuisance_bound: float | None = None,
    floors: Floors | None = None,
    compared: Mapping[str, bool] | None = None,
) -> pd.DataFrame:
    """One row per model and split; `below_bound` marks memorisation: an RMS error under the electronics-only
    Cramér-Rao bound, or a median error under half of it (an unbiased estimator at the bound, Gaussian errors
    in 2-D, has a median error of 0.67 to 0.83 times its RMS: a median below half the bound cannot be one).
    The bound with nuisances is a column beside it (`rms_over_crb_nuisance`), not a flag. With the floors of
    physical_limit.parquet, an RMS error below the label-noise floor of the row's own split flags it too, and each
    row gets its split's floor and its excess over it (`floortext.add_floor_columns`)."""
    table = add_floor_columns(pd.DataFrame([r.row() for r in results]), floors)
    compared = compared or {}  # without a say (a bound's spread unknown): every bound is compared
    # a pooled bound held by positions where it exceeds the skin (infinite, or huge: on the FE skin a press that
    # shuts every channel it reaches tells which channels, not where among them) has no ratio and flags nothing (`comparable`:
    # no estimator answering on the skin is unbiased there), and rms / inf = 0 (or rms / 1e5) read as "far below"
    if nuisance_bound is not None:
        table["crb_nuisance_rms_mm"] = nuisance_bound
        table["rms_over_crb_nuisance"] = _ratio(table["rms_error_mm"], nuisance_bound, compared.get("crb_nuisance_mm"))
    if bound is not None:
        table["crb_rms_mm"] = bound
        table["rms_over_crb"] = _ratio(table["rms_error_mm"], bound, compared.get("crb_mm"))
    if bound is not None and compared.get("crb_mm", True) and np.isfinite(bound):
        table["below_bound"] = (table["rms_error_mm"] < bound) | (table["median_error_mm"] < MEDIAN_BOUND_SHARE * bound)
    else:  # no bound, or one held by positions beyond the skin: nothing is below it
        table["below_bound"] = False
    table["below_bound"] = table["below_bound"] | below_label_floor(table)
    return table


def _skin_size_mm(data: BaselineData) -> float:
    """The skin's largest extent (layout bounds, else the pressed positions' extent)."""
    if data.layout is not None:
        x0, y0, x1, y1 = data.layout.bounds_mm  # type: ignore[attr-defined]
        return float(max(x1 - x0, y1 - y0))
    return float(np.max(np.ptp(data.y, axis=0)))


def result_warnings(table: pd.DataFrame, data: BaselineData, bound: float | None) -> list[str]:
    """Warnings about the results: errors larger than the skin, results below the physical bound."""
    notes = []
    size = _skin_size_mm(data)
    for row in table.itertuples(index=False):
        if float(row.mean_error_mm) > size:  # type: ignore[arg-type]
            notes.append(
                f"{row.model} ({row.split}): mean error {row.mean_error_mm:.1f} mm is larger than the skin "
                f"({size:.0f} mm): it extrapolates; read its figures as a failure, not as an error size"
            )
        if row.below_bound:
            floor = getattr(row, "label_floor_rms_mm", 0.0)
            notes.append(
                f"{row.model} ({row.split}): RMS error {row.rms_error_mm:.3g} mm, median {row.median_error_mm:.3g} mm "
                f"against the electronics-only Cramér-Rao bound {bound if bound is not None else float('nan'):.3g} mm "
                f"(RMS) and its split's label-noise floor {floor:.3g} mm (RMS): no estimator of one press can do "
                "that; it memorises the training positions or uses the campaign's order"
            )
    return notes

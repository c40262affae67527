"""What the terminal shows after a baseline report: the fixed-width table, the bounds and floors, and where the report
is (`report_summary`, printed by `neatskin baselines` and by a campaign's report). Figures with report.md's sig3."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from neatskin.baselines.tabletext import sig3

if TYPE_CHECKING:
    from neatskin.baselines.report import Report


def format_table(table: pd.DataFrame) -> str:
    """A fixed-width text table: mean ± std over repeats [95 % interval of the mean] per figure."""
    header = (
        f"{'model':<12} {'split':<8} {'rep':>3} {'n_test':>6} {'mean err mm [95% CI]':>28} {'median mm':>9} "
        f"{'RMS mm':>8} {'<=r %':>6} {'fail %':>6} {'fit s':>7} {'us/row':>8}"
    )
    # a ratio column only where some result is compared with its bound (an all-NaN column reads as a fault)
    has_bound = "rms_over_crb" in table.columns and bool(np.isfinite(table["rms_over_crb"].to_numpy(float)).any())
    if has_bound:
        header += f" {'RMS/CRB':>8}"
    has_nuisance = "rms_over_crb_nuisance" in table.columns
    has_nuisance = has_nuisance and bool(np.isfinite(table["rms_over_crb_nuisance"].to_numpy(float)).any())
    if has_nuisance:
        header += f" {'RMS/CRBn':>8}"
    lines = [header, "-" * len(header)]
    for row in table.itertuples(index=False):
        mean = f"{row.mean_error_mm:.3g} ± {row.mean_error_mm_std:.2g} [{row.mean_error_mm_lo:.3g}, {row.mean_error_mm_hi:.3g}]"
        line = (
            f"{row.model:<12} {row.split:<8} {row.n_repeats:>3} {row.n_test:>6} {mean:>28} {row.median_error_mm:>9.3g} "
            f"{row.rms_error_mm:>8.3g} {row.within_probe_pct:>6.1f} {row.failure_pct:>6.1f} {row.fit_time_s:>7.3f} "
            f"{row.predict_time_per_sample_us:>8.1f}"
        )
        if has_bound:
            line += f" {row.rms_over_crb:>8.3g}"
        if has_nuisance:
            line += f" {row.rms_over_crb_nuisance:>8.3g}"
        if row.below_bound:
            line += "  MEMORISATION (below the bound)"
        lines.append(line)
    return "\n".join(lines)


def report_summary(report: Report) -> str:
    """What the terminal shows after a report: the table, the bounds and floors, and where the report is (the CLIs
    print it). Figures with report.md's sig3, so the terminal and the file read the same."""
    lines = [format_table(report.table)]
    for name, pooled, spread, compared in zip(
        ("electronics only", "with depth, drift and placement as nuisances"),
        (report.bound_rms_mm, report.bound_nuisance_rms_mm),
        report.spreads,
        report.compared,
        strict=False,
    ):
        if pooled is None:
            continue
        over = ""
        if spread is not None:
            over = f"median {sig3(spread[0])} mm over {spread[2]} positions, above the probe radius at {spread[1]}"
        if compared:
            where = f" ({over})" if spread is not None and spread[1] else ""
            lines.append(f"Cramér-Rao bound (RMS over positions), {name}: {sig3(pooled)} mm{where}")
        else:  # an infinite or huge pooled RMS says nothing: the median does (report.md, "Physical limit")
            lines.append(
                f"Cramér-Rao bound, {name}: {over or 'no median'}; beyond the skin at some positions (a channel shut "
                "under the probe), so no result is compared with it"
            )
    if report.floors is not None:
        f = report.floors
        new_positions, by_row = f.label_mm.get("new_positions"), f.label_mm.get("by_row")
        label = ", ".join(
            f"{sig3(v[0])} mm {what}"
            for what, v in (("for new positions", new_positions), ("by row", by_row))
            if v is not None
        )
        landing = f"landing-point bound median {sig3(f.landing_spread[0])} mm over {f.landing_spread[2]} positions"
        lines.append(f"Floors (report.md, Floors): label-noise floor (mean) {label}; {landing}")
    lines.append(f"wrote {report.files['report']} ({report.time_s:.1f} s)")
    return "\n".join(lines)

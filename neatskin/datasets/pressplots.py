"""Curator plots of single presses and of drift (PNG, matplotlib Agg): R per pair and the FSR against time for
one press, from its recorded waveforms (or, without them, from its features), and each pair's baseline R
against press order.

From waveforms, R per pair and sweep is RMS(V) / RMS(I) over the pair's whole live window (the sweep's slots
are break, settle, live; their pair order is the manifest's `sweep.pair_order` when recorded, else the layout's
pair order, which is checked against the press's stored baseline before anything is drawn). Only the ground
floor and the dataset reader are used: no acquisition code.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.datasets.manifest import read_manifest
from neatskin.datasets.reader import pair_labels_from_columns, read_presses, read_waveforms
from neatskin.errors import DataError

FIGSIZE_IN = (9.0, 6.5)
DPI = 100
SLOT_MATCH_TOLERANCE = 0.05  # a slot's first-sweep R within 5 % of its pair's stored baseline
# a cut pair's recorded sweep reads open above this many times its first sweep: a pinched channel reads RMS(V) over
# a collapsed current, about 1e8 ohm on a 3e3 ohm pair (10^4 to 10^5 fold); a press moves an open pair a few fold
OPEN_FOLD = 100.0


@dataclass(frozen=True)
class PressSeries:
    """One press against time: R per sweep and pair, and the FSR signal."""

    press_id: int
    source: str  # "waveforms" or "features"
    pairs: tuple[str, ...]
    time_s: np.ndarray  # (points,) time of each R point, s from the press record's start
    resistance_ohm: np.ndarray  # (points, pairs)
    fsr_time_s: np.ndarray  # (fsr points,)
    fsr: np.ndarray  # (fsr points,) volts (waveforms) or newtons (features: 0, peak, 0)
    fsr_unit: str
    onset_s: float | None
    offset_s: float | None
    # (pairs,) True where the press cut the pair off (its row's R and dR = +inf, a channel pinched shut): the row
    # holds no baseline for it, and its pressed R is infinite
    cut: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


def _row(df: pd.DataFrame, press_id: int, folder: Path) -> pd.Series:
    rows = df[df["press_id"] == press_id]
    if rows.empty:
        ids = df["press_id"].to_numpy()
        raise DataError(
            f"no press {press_id} in this dataset",
            file=str(folder),
            field="--press",
            fix=f"give a press id between {ids.min()} and {ids.max()}" if len(ids) else "the dataset has no presses",
        )
    return rows.iloc[0]


def _opt(value: float | None) -> float | None:
    return None if value is None or not np.isfinite(value) else float(value)


def press_series(folder: str | os.PathLike, press_id: int) -> PressSeries:
    """R per pair and the FSR against time for `press_id`: from waveforms when the campaign recorded them."""
    folder = Path(folder)
    df = read_presses(folder)
    row = _row(df, press_id, folder)
    pairs = pair_labels_from_columns(df)
    labels = tuple(p.label for p in pairs)
    r = np.array([row[f"R_ohm_{p.i}_{p.j}"] for p in pairs], dtype=float)
    dr = np.array([row[f"dR_ohm_{p.i}_{p.j}"] for p in pairs], dtype=float)
    cut = ~(np.isfinite(r) & np.isfinite(dr))
    base = np.where(cut, np.nan, r - np.where(cut, 0.0, dr))  # a cut pair: no baseline (and no inf - inf warning)
    onset, offset = _opt(row["fsr_onset_s"]), _opt(row["fsr_offset_s"])
    if (folder / "waveforms").is_dir():
        series = _from_waveforms(folder, press_id, labels, base, onset, offset)
        return PressSeries(**{**series.__dict__, "cut": cut})
    # features only: the baseline until the FSR onset, the pressed value until its offset, then the baseline
    t_on = onset if onset is not None else 1.0
    t_off = offset if offset is not None else t_on + 1.0
    time_s = np.array([0.0, t_on, t_on, t_off, t_off, t_off + t_on])
    resistance = np.vstack([base, base, r, r, base, base])
    peak = _opt(row["fsr_peak_n"]) or 0.0
    return PressSeries(
        press_id,
        "features",
        labels,
        time_s,
        resistance,
        np.array([0.0, t_on, t_on, t_off, t_off, t_off + t_on]),
        np.array([0.0, 0.0, peak, peak, 0.0, 0.0]),
        "N (peak)",
        onset,
        offset,
        cut,
    )


def _from_waveforms(folder, press_id, labels, baseline_ohm, onset, offset) -> PressSeries:
    sweep = read_manifest(folder).get("sweep") or {}
    try:
        rate = float(sweep["rate_hz"])
        n = int(sweep["samples"])
        settle, live = int(sweep["settle_samples"]), int(sweep["live_samples"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(
            f"the manifest's sweep lacks {exc}",
            file=str(folder / "manifest.json"),
            field="sweep",
            fix="plot from a campaign written by `neatskin campaign run`",
        ) from exc
    n_pairs = len(labels)
    slot = n // n_pairs
    order = np.asarray(sweep.get("pair_order", range(n_pairs)), dtype=int)
    wave = read_waveforms(folder, [press_id])
    v, i = wave["voltage_v"].to_numpy(float), wave["current_a"].to_numpy(float)
    n_sweeps = len(v) // n
    if n_sweeps < 1 or slot * n_pairs != n or slot < settle + live or sorted(order) != list(range(n_pairs)):
        raise DataError(
            f"press {press_id}'s {len(v)} samples do not split into sweeps of {n} samples ({n_pairs} slots)",
            file=str(folder / "waveforms"),
            fix="plot it from features: move the waveforms folder aside",
        )
    start = np.arange(n_pairs) * slot + (slot - live)  # break and settle come first in a slot
    idx = start[:, None] + np.arange(live)[None, :]  # (slots, live)
    v_s = v[: n_sweeps * n].reshape(n_sweeps, n)[:, idx]  # (sweeps, slots, live)
    i_s = i[: n_sweeps * n].reshape(n_sweeps, n)[:, idx]
    with np.errstate(divide="ignore", invalid="ignore"):
        r_slots = np.sqrt((v_s**2).mean(axis=2)) / np.sqrt((i_s**2).mean(axis=2))
    r = np.empty_like(r_slots)
    r[:, order] = r_slots
    ok = np.isfinite(baseline_ohm) & np.isfinite(r[0])
    rel = np.abs(r[0][ok] / baseline_ohm[ok] - 1.0)
    if rel.size and rel.max() > SLOT_MATCH_TOLERANCE:
        worst = labels[int(np.flatnonzero(ok)[np.argmax(rel)])]
        raise DataError(
            f"the first sweep's R of pair {worst} is {rel.max():.0%} off its stored baseline: the sweep's pair "
            "order is not the layout's",
            file=str(folder / "manifest.json"),
            field="sweep.pair_order",
            fix="record the mux visiting order as sweep.pair_order in the manifest",
        )
    time_s = (np.arange(n_sweeps)[:, None] * n + idx.mean(axis=1)[None, :]) / rate  # (sweeps, slots)
    mid = time_s[:, order.argsort()].mean(axis=1)
    fsr = wave["fsr_v"].to_numpy(float)
    return PressSeries(press_id, "waveforms", labels, mid, r, np.arange(len(fsr)) / rate, fsr, "V", onset, offset)


def plot_press(folder: str | os.PathLike, press_id: int, out: str | os.PathLike) -> Path:
    """PNG of one press: the FSR (top) and R of every pair (bottom) against time, FSR onset/offset marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = press_series(folder, press_id)
    fig, (ax_f, ax_r) = plt.subplots(2, 1, figsize=FIGSIZE_IN, sharex=True, height_ratios=(1, 2.2))
    ax_f.plot(s.fsr_time_s, s.fsr, color="0.25", lw=0.8)
    ax_f.set_ylabel(f"FSR ({s.fsr_unit})")
    cut = s.cut if len(s.cut) == len(s.pairs) else np.zeros(len(s.pairs), bool)
    is_open = open_points(s.resistance_ohm, cut)
    drawn = np.where(is_open, np.nan, s.resistance_ohm)  # open points at the top (_mark_cut), not on the R scale
    top = set(largest_changes(drawn, cut))
    highlight = iter(f"C{k}" for k in range(10) if k != 3)  # the default cycle, its red (C3) kept for "cut"
    for k, label in enumerate(s.pairs):
        ax_r.plot(
            s.time_s,
            drawn[:, k],  # matplotlib leaves a gap at a NaN point: the open ones are marked at the top below
            color="tab:red" if cut[k] else next(highlight) if k in top else "0.72",
            lw=1.5 if k in top else 0.7,
            label=label if k in top else None,
            marker="." if s.source == "waveforms" else None,
            ls="-" if s.source == "waveforms" else "--",  # dashed: a schematic, not a measured trace
            ms=3,
            zorder=3 if k in top else 2,
        )
    _mark_cut(ax_r, s, cut, is_open)
    for ax in (ax_f, ax_r):
        for t, name in ((s.onset_s, "FSR onset"), (s.offset_s, "FSR offset")):
            if t is not None:
                ax.axvline(t, color="tab:red", ls="--", lw=0.8)
                if ax is ax_f:
                    ax.annotate(
                        name,
                        (t, 1.0),
                        xycoords=("data", "axes fraction"),
                        fontsize=8,
                        color="tab:red",
                        ha="left",
                        va="bottom",
                    )
    ax_r.set_ylabel("R per pair (ohm)")
    ax_r.set_xlabel("time since the press record began (s)")
    kept = len(s.pairs) - int(cut.sum())
    ax_r.legend(
        title=f"{len(top)} largest changes\nof the {kept} pairs{' not cut' if cut.any() else ''}\n(others grey)",
        fontsize=8,
        title_fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),  # beside the axes: inside, it hid the top where the cut pairs are marked
    )
    title = press_title(s, cut)
    if s.source == "features":
        for ax in (ax_f, ax_r):
            ax.text(
                0.5,
                0.5,
                "rebuilt from features, not recorded",
                transform=ax.transAxes,
                ha="center",
                va="center",
                fontsize=16,
                color="0.5",
                alpha=0.35,
                rotation=12,
                zorder=1,
            )
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out


def press_title(s: PressSeries, cut: np.ndarray) -> str:
    """The press plot's title: what it shows (recorded, or a schematic from features), and how many pairs the press
    cut off (their row's R = inf), marked at the top of the R axis, as the drift and sensitivity plots count theirs."""
    note = (
        f"\n{int(cut.sum())} of the {len(s.pairs)} pairs cut off by the press (R = inf in its row"
        f"{': no pressed value, no baseline' if s.source == 'features' else ''}), marked 'cut' at the top"
        if cut.any()
        else ""
    )
    if s.source == "waveforms":
        return (
            f"press {s.press_id}: R of {len(s.pairs)} pairs and FSR, recorded (one point per sweep: RMS over each "
            f"pair's live window){note}"
        )
    return (
        f"press {s.press_id}: SCHEMATIC rebuilt from features, not recorded (the campaign stored no waveforms)\n"
        f"baseline and pressed R of {len(s.pairs)} pairs and the FSR peak, stepped at the FSR onset and offset{note}"
    )


def largest_changes(resistance_ohm: np.ndarray, cut: np.ndarray, count: int = 5) -> list[int]:
    """The pairs (column indices) of the `count` largest changes max - min over their finite points, among those the
    press did not cut off; computed on finite values only (a cut pair's inf - inf was NaN and numpy's warning)."""
    finite = np.isfinite(resistance_ohm)
    hi = np.max(np.where(finite, resistance_ohm, -np.inf), axis=0, initial=-np.inf)
    lo = np.min(np.where(finite, resistance_ohm, np.inf), axis=0, initial=np.inf)
    usable = finite.any(axis=0) & ~cut
    change = np.full(resistance_ohm.shape[1], -1.0)
    change[usable] = hi[usable] - lo[usable]
    ranked = [int(k) for k in np.argsort(change, kind="stable")[::-1] if usable[k]]
    return ranked[:count]


def open_points(resistance_ohm: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """(points, pairs): True at a cut pair's point that reads open, +inf (the features' pressed value) or above
    OPEN_FOLD times the pair's first finite point (a recorded sweep over a pinched channel); False elsewhere."""
    finite = np.isfinite(resistance_ohm)
    first_k = np.argmax(finite, axis=0)
    first = np.where(finite.any(axis=0), resistance_ohm[first_k, np.arange(resistance_ohm.shape[1])], np.inf)
    with np.errstate(invalid="ignore"):  # NaN points (a schematic's missing baseline) compare False: not open
        high = np.isposinf(resistance_ohm) | (finite & (resistance_ohm > OPEN_FOLD * np.abs(first)))
    return high & cut[None, :]


def _mark_cut(ax, s: PressSeries, cut: np.ndarray, is_open: np.ndarray) -> None:
    """The cut pairs' open points drawn at the top of the R axis (x in data, y in axes fraction) as red x's,
    joined in the schematic (its pressed step), with the label 'cut' and the pairs: never silently left out."""
    if not cut.any():
        return
    inf_time = s.time_s[is_open.any(axis=1)]
    if not len(inf_time):  # a recorded trace that stays finite: mark the pressed span (or the record) instead
        inf_time = np.array([s.onset_s or s.time_s[0], s.offset_s or s.time_s[-1]])
    names = [p for p, c in zip(s.pairs, cut) if c]
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + 0.15 * (hi - lo))  # headroom: the marks above the highest finite trace, not on it
    ax.plot(
        inf_time,
        np.full(len(inf_time), 0.96),
        transform=ax.get_xaxis_transform(),
        color="tab:red",
        marker="x",
        ls="-" if s.source == "features" else "none",
        lw=1.5,
        clip_on=False,
        zorder=4,
        label=f"cut: R = inf ({len(names)} pairs, at the top)",
    )
    shown = ", ".join(names[:8]) + (f" +{len(names) - 8}" if len(names) > 8 else "")
    ax.annotate(
        f"cut ({len(names)}): {shown}",
        (float(np.mean(inf_time)), 0.96),
        xycoords=("data", "axes fraction"),
        xytext=(0, -4),
        textcoords="offset points",
        ha="center",
        va="top",
        fontsize=8,
        color="tab:red",
    )


def _pair_values(df: pd.DataFrame) -> tuple[pd.DataFrame, tuple[str, ...], np.ndarray, np.ndarray]:
    """(rows sorted by press id, pair labels, R and dR as (presses, pairs) arrays in pair order)."""
    df = df.sort_values("press_id", kind="stable")
    pairs = pair_labels_from_columns(df)
    r = df[[f"R_ohm_{p.i}_{p.j}" for p in pairs]].to_numpy(float)
    dr = df[[f"dR_ohm_{p.i}_{p.j}" for p in pairs]].to_numpy(float)
    return df, tuple(p.label for p in pairs), r, dr


def cut_off(df: pd.DataFrame) -> np.ndarray:
    """(presses, pairs) in press-id order: True where the press cut the pair off (a channel pinched shut leaves R and
    dR = +inf, its open_circuit flag on the row): the row holds no baseline for that pair."""
    _, _, r, dr = _pair_values(df)
    return ~(np.isfinite(r) & np.isfinite(dr))


def baseline_drift_pct(df: pd.DataFrame) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """(press ids, pair labels, (presses, pairs) baseline R = R - dR as % change from each pair's first press that
    did not cut it off). Where a press cut the pair off (cut_off) the value is NaN: R - dR would be inf - inf, and
    a cut first press would have made the pair's whole line NaN."""
    df, labels, r, dr = _pair_values(df)
    cut = ~(np.isfinite(r) & np.isfinite(dr))
    base = np.where(cut, np.nan, r - np.where(cut, 0.0, dr))  # no inf - inf (numpy's RuntimeWarning)
    first_kept = np.argmax(~cut, axis=0)  # each pair's first uncut press (0 when every press cut it: NaN below)
    first = base[first_kept, np.arange(base.shape[1])] if len(base) else np.full(base.shape[1], np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):  # a baseline of exactly 0 ohm: inf, not a warning
        pct = 100.0 * (base / first - 1.0)
    return df["press_id"].to_numpy(int), labels, pct


def drift_title(labels: tuple[str, ...], pct: np.ndarray, cut: np.ndarray) -> str:
    """The drift plot's title: what it shows, its largest change, and the cut-off values it left out."""
    span = np.nanmax(np.abs(pct[np.isfinite(pct)])) if np.isfinite(pct).any() else 0.0
    title = f"baseline drift of {len(labels)} pairs over {pct.shape[0]} presses (largest |change| {span:.3f} %)"
    if cut.any():
        pairs_cut, presses_cut, values = int(cut.any(axis=0).sum()), int(cut.any(axis=1).sum()), int(cut.sum())
        title += (
            f"\nleft out: {values} value{'s' if values != 1 else ''} where the press cut the pair off (R = inf; "
            f"{presses_cut} press{'es' if presses_cut != 1 else ''}, {pairs_cut} pair{'s' if pairs_cut != 1 else ''}):"
            " gaps in the lines;\neach pair's reference is its first press that did not cut it off"
        )
    return title


def plot_drift(folder: str | os.PathLike, out: str | os.PathLike) -> Path:
    """PNG of every pair's baseline R against press order (% from its first press that did not cut it off), the median
    across pairs bold; the values of cut-off pairs are left out (gaps), and the title says how many."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    df = read_presses(folder)
    ids, labels, pct = baseline_drift_pct(df)
    cut = cut_off(df)
    fig, ax = plt.subplots(figsize=(FIGSIZE_IN[0], 4.5))
    cmap = plt.get_cmap("viridis")
    for k in range(len(labels)):
        ax.plot(ids, pct[:, k], color=cmap(k / max(len(labels) - 1, 1)), lw=0.7, alpha=0.6)
    finite = np.where(np.isfinite(pct), pct, np.nan)
    kept = np.isfinite(finite).any(axis=1)  # a press that cut every pair off has no median (nanmedian would warn)
    median = np.full(len(ids), np.nan)
    median[kept] = np.nanmedian(finite[kept], axis=1)
    ax.plot(ids, median, color="k", lw=2.0, label="median over pairs")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlabel("press id (order pressed)")
    ax.set_ylabel("baseline R (R - dR): % from the reference")
    ax.legend(fontsize=8)
    ax.set_title(drift_title(labels, pct, cut), fontsize=9 if cut.any() else 10)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    return out

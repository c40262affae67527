"""A study's files: each candidate's durable part (its row), map parquet and map PNG; the Pareto front of error
against electrodes against sweep time; the Pareto plot and report.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from neatskin.datasets.durable import write_bytes_durably, write_durably
from neatskin.design.evaluate import CandidateResult
from neatskin.design.study import PARTS, Study
from neatskin.design.validate import existing_section

MAPS = "maps"  # its per-candidate bound maps (parquet, png)
ERROR_COLUMN = "bound_mean_capped_mm"
PARETO_COLUMNS = (ERROR_COLUMN, "electrodes", "sweep_time_s")
# candidates compete only with candidates on the same skin (same grid, channels, probe and depth)
SKIN_COLUMNS = ("nx", "ny", "pitch_mm", "channel_width_mm", "channel_height_mm", "probe_diameter_mm", "depth_mm")


def write_candidate(out_dir: Path, result: CandidateResult, png: bool = True) -> None:
    """Map parquet and PNG first, the row last: the row's presence marks the candidate done."""
    cid = result.candidate_id
    write_durably(out_dir / MAPS / f"{cid}.parquet", lambda h: result.map_frame.to_parquet(h, index=False))
    if png:
        plot_map(result.row, result.map_frame, out_dir / MAPS / f"{cid}.png")
    row = pd.DataFrame([result.row])
    write_durably(out_dir / PARTS / f"{cid}.parquet", lambda h: row.to_parquet(h, index=False))


def plot_map(row: dict, frame: pd.DataFrame, path: Path) -> None:
    """The bound map (log colour scale, capped at 10 x pitch) with the channels and the electrodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    n = int(round(math.sqrt(len(frame))))
    x = frame["x_mm"].to_numpy().reshape(n, n)
    y = frame["y_mm"].to_numpy().reshape(n, n)
    pitch = float(row["pitch_mm"])
    panels = [("bound_mm", "position bound (mm), depth unknown", f"median {row['bound_median_mm']:.3g} mm")]
    if "inversion_error_mm" in frame:
        panels.append(("inversion_error_mm", "inversion error (mm)", f"mean {row['inversion_error_mean_mm']:.3g} mm"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.4), squeeze=False)
    nx, ny = int(row["nx"]), int(row["ny"])
    nodes = np.array([[int(v) for v in n.split(",")] for n in str(row["electrode_nodes"]).split(";")]) * pitch
    for ax, (column, label, summary) in zip(axes[0], panels):
        values = frame[column].to_numpy().reshape(n, n)
        shown = np.clip(np.where(np.isfinite(values), values, 10 * pitch), 1e-3, 10 * pitch)
        norm = LogNorm(vmin=max(shown.min(), 1e-3), vmax=10 * pitch)
        mesh = ax.pcolormesh(x, y, shown, norm=norm, shading="nearest")
        fig.colorbar(mesh, ax=ax, label=label)
        for i in range(nx):
            ax.plot([i * pitch, i * pitch], [0, (ny - 1) * pitch], color="white", lw=0.6, alpha=0.7)
        for j in range(ny):
            ax.plot([0, (nx - 1) * pitch], [j * pitch, j * pitch], color="white", lw=0.6, alpha=0.7)
        ax.plot(nodes[:, 0], nodes[:, 1], "o", ms=7, mfc="red", mec="black", label="electrode")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_title(f"{nx} x {ny} {row['placement']} {row['electrodes']} el.: {summary}", fontsize=9)
    fig.tight_layout()
    write_durably(path, lambda h: fig.savefig(h, format="png", dpi=80))
    plt.close(fig)


def pareto_mask(frame: pd.DataFrame, columns: tuple[str, ...] = PARETO_COLUMNS) -> np.ndarray:
    """True for candidates that no candidate on the same skin dominates (at least as good on every column,
    better on one; all minimised)."""
    mask = np.zeros(len(frame), dtype=bool)
    for _, index in frame.groupby(list(SKIN_COLUMNS), sort=False).indices.items():
        mask[index] = _front(frame.iloc[index], columns)
    return mask


def _front(frame: pd.DataFrame, columns: tuple[str, ...]) -> np.ndarray:
    values = frame[list(columns)].to_numpy(dtype=float)
    values = np.where(np.isnan(values), np.inf, values)
    le = np.all(values[:, None, :] <= values[None, :, :], axis=2)  # le[j, i]: j at least as good as i
    lt = np.any(values[:, None, :] < values[None, :, :], axis=2)
    dominated = np.any(le & lt, axis=0)
    return ~dominated


def plot_pareto(frame: pd.DataFrame, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    front = pareto_mask(frame)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    markers = dict(zip(("boundary", "optimised", "interior", "every_k", "explicit"), "os^Dv"))
    for strategy, group in frame.groupby("strategy", sort=False):
        for ax, xcol, scale in ((axes[0], "electrodes", 1.0), (axes[1], "sweep_time_s", 1e3)):
            ax.plot(
                group[xcol] * scale,
                group[ERROR_COLUMN],
                markers.get(str(strategy), "x"),
                ms=7,
                alpha=0.8,
                label=str(strategy),
            )
    skins = frame.groupby(list(SKIN_COLUMNS), sort=False).indices
    for ax, xcol, scale in ((axes[0], "electrodes", 1.0), (axes[1], "sweep_time_s", 1e3)):
        for n, (skin_key, index) in enumerate(skins.items()):
            skin: tuple[Any, ...] = tuple(skin_key)  # type: ignore[arg-type]
            part = frame.iloc[index]
            f = part[front[index]].sort_values(xcol)
            label = f"front, {skin[0]} x {skin[1]} @ {skin[2]:g} mm" if len(skins) > 1 else "Pareto front"
            ax.step(f[xcol] * scale, f[ERROR_COLUMN], where="post", color=f"C{7 + n % 3}", lw=1, label=label)
            ax.plot(f[xcol] * scale, f[ERROR_COLUMN], "o", mfc="none", mec="black", ms=12)
        errors = frame[ERROR_COLUMN].to_numpy(dtype=float)
        if np.nanmax(errors) > 20 * np.nanmin(errors):
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.set_ylabel("mean position bound, capped at pitch/2 (mm)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_xlabel("electrodes")
    axes[1].set_xlabel("sweep time per measurement (ms)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(value: Any, digits: int = 3) -> str:
    value = float(value)
    if not math.isfinite(value):
        return "inf" if value > 0 else "n/a"
    return f"{value:.{digits}g}"


def _comparison(frame: pd.DataFrame, learned: bool, inverted: bool, kind: str) -> list[str]:
    """Boundary against optimised placement at each electrode count on each skin (where the study has both)."""
    both = frame[frame["strategy"].isin(["boundary", "optimised"])]
    keys = [*SKIN_COLUMNS, "electrodes"]
    rows = []
    for key_, group in both.groupby(keys, sort=False):
        key: tuple[Any, ...] = tuple(key_)  # type: ignore[arg-type]
        by = group.set_index("strategy")
        if not {"boundary", "optimised"} <= set(by.index):
            continue
        b, o = by.loc["boundary"], by.loc["optimised"]
        cells = [
            f"{key[0]} x {key[1]}",
            str(key[-1]),
            f"{_fmt(b['bound_median_mm'])} -> {_fmt(o['bound_median_mm'])} "
            f"({(o['bound_median_mm'] / b['bound_median_mm'] - 1) * 100:+.0f} %)",
            f"{_fmt(b['bound_p90_mm'])} -> {_fmt(o['bound_p90_mm'])}",
            f"{_fmt(b['bound_mean_capped_mm'])} -> {_fmt(o['bound_mean_capped_mm'])}",
            f"{b['criterion_' + kind]:.4g} -> {o['criterion_' + kind]:.4g}",
            f"`{o['electrode_nodes']}`",
        ]
        if inverted:
            cells.insert(
                5,
                f"{_fmt(b['inversion_error_mean_mm'])} +- {_fmt(b['inversion_error_std_mm'], 2)} -> "
                f"{_fmt(o['inversion_error_mean_mm'])} +- {_fmt(o['inversion_error_std_mm'], 2)}",
            )
        if learned:
            cells.insert(
                -2,
                f"{_fmt(b['learned_error_mean_mm'])} +- {_fmt(b['learned_error_std_mm'], 2)} -> "
                f"{_fmt(o['learned_error_mean_mm'])} +- {_fmt(o['learned_error_std_mm'], 2)}",
            )
        rows.append("| " + " | ".join(cells) + " |")
    if not rows:
        return []
    head = "| skin | electrodes | bound median (mm) | bound p90 (mm) | capped mean (mm) |"
    head += " inversion mean (mm) |" if inverted else ""
    head += " learned (mm, mean +- std over seeds) |" if learned else ""
    head += f" {kind} criterion (optimised on it) | optimised junctions (i,j) |"
    return [
        "",
        "## Boundary against optimised placement",
        "",
        "Boundary -> optimised, same skin, same electrode count (so the same sweep time).",
        "",
        head,
        "|" + "---|" * (head.count("|") - 1),
        *rows,
    ]


def write_report(out_dir: Path, study: Study, frame: pd.DataFrame) -> None:
    plot_pareto(frame, out_dir / "pareto.png", f"study {study.name}: error against electrodes and sweep time")
    front = pareto_mask(frame)
    learned = study.learned.enabled
    inverted = study.inversion.enabled
    lines = [
        f"# Design study `{study.name}`",
        "",
        study.description,
        "",
        f"Study file: `{Path(study.source).name}`; scene `{study.scene}`, skin model `{study.fidelity}`, "
        f"{study.press_grid} x {study.press_grid} presses per candidate (cell-centred over the junction bounds), "
        f"noise model `{study.noise_model}`, placement criterion {study.criterion}-optimal, seed {study.seed}.",
        "",
        "![Pareto front](pareto.png)",
        "",
        "## What the numbers are",
        "",
        "- **bound**: the Cramér-Rao bound on the RMS position error of one press, sqrt(trace(F^-1)), with the "
        "press depth an unknown nuisance parameter (Schur complement); computed from the adjoint Jacobian of the "
        "skin model, not fitted to any data. It is a *local* bound: it is infinite or very large where a press "
        "moves no pair's resistance to first order (on a channel's centre line the pinch is symmetric across it), "
        "so the table gives the median and the 90th percentile, and the mean of the bound capped at half the "
        "pitch (*capped mean*, the error column of the Pareto front).",
        f"- **noise**: per-pair standard deviation of one estimate; `{study.noise_model}` model "
        f"(voltage noise {study.voltage_noise_v:g} V, current noise {study.current_noise_a:g} A, "
        f"{'16-bit ADC quantisation, ' if study.quantise else ''}{study.live_samples} live samples, "
        f"{study.sweeps_per_press} sweep(s) per press); the baseline is assumed known exactly. Assumed, not fitted.",
        f"- **sweep time** per measurement = pairs x (break {study.break_samples} + settle {study.settle_samples} "
        f"+ live {study.live_samples} samples) / {study.rate_hz:g} Hz.",
        f"- **peak V**: a campaign protocol's own electrical check (`neatskin.rig.protocol.electrical_check`) on "
        f"each candidate skin: {study.amplitude_a * 1e3:g} mA x (largest pair R_eq of the undeformed skin x "
        f"{study.press_margin:g} press margin + 2 x {study.r_on_ohm:g} ohm R_on + {study.r_on_mismatch_ohm:g} ohm "
        f"mismatch), against the lowest of the mux rails (+-{study.rails_v:g} V), the galvanostat compliance "
        f"({study.compliance_v:g} V) and the ADC range over the voltage gain ({study.adc_range_v:g} V / "
        f"{study.voltage_gain:g}); **limit V** is that lowest limit. All assumed (the study's `[excitation]` and "
        "`[acquisition]` keys), not measured; candidates.parquet also holds the largest pair R_eq over the "
        "simulated presses (`max_pair_ohm`) and whether the press margin covers it (`press_margin_covers`).",
    ]
    if inverted:
        inv = study.inversion
        lines.append(
            f"- **inversion**: the press located by the skin model itself from its noisy resistances (library search "
            f"over {inv.library} x {inv.library} positions x depths {', '.join(f'{o:+g}' for o in inv.depth_offsets_mm)} "
            f"mm, then {inv.iterations} Gauss-Newton steps on x, y and depth from the {inv.starts} best matches, the "
            f"least misfit kept); Euclidean error, mean +- std over "
            f"{inv.draws} noise draws, and the median and 90th percentile over presses. Unlike the bound it is global: "
            "it counts the presses the search sends to a wrong basin (an upper estimate of the model's own error)."
        )
    if learned:
        spec = study.learned
        lines.append(
            f"- **learned**: mean Euclidean test error of `{spec.model}` on a simulated features-only dataset "
            f"({spec.positions} positions x {spec.repeats} repeats, {spec.test_share:.0%} of positions held out), "
            f"mean +- std over {spec.seeds} seeds (a new dataset and split each)."
        )
    lines += [
        "",
        "## Candidates",
        "",
        "| grid | placement | electrodes | pairs | sweep (ms) | bound median (mm) | bound p90 (mm) | capped mean (mm) "
        "| known-depth median (mm) | peak V | limit V | within |"
        + (" inversion mean (mm) | inversion median / p90 (mm) |" if inverted else "")
        + (" learned (mm) |" if learned else "")
        + " Pareto (per skin) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|"
        + ("---|---|" if inverted else "")
        + ("---|" if learned else "")
        + "---|",
    ]
    for k, (_, row) in enumerate(frame.iterrows()):
        inversion_cell = (
            f" {_fmt(row['inversion_error_mean_mm'])} +- {_fmt(row['inversion_error_std_mm'], 2)} "
            f"| {_fmt(row['inversion_error_median_mm'])} / {_fmt(row['inversion_error_p90_mm'])} |"
            if inverted
            else ""
        )
        learned_cell = (
            f" {_fmt(row['learned_error_mean_mm'])} +- {_fmt(row['learned_error_std_mm'], 2)} |" if learned else ""
        )
        lines.append(
            f"| {row['nx']} x {row['ny']} @ {row['pitch_mm']:g} mm | {row['placement']} | {row['electrodes']} "
            f"| {row['pairs']} | {row['sweep_time_s'] * 1e3:.1f} | {_fmt(row['bound_median_mm'])} "
            f"| {_fmt(row['bound_p90_mm'])} | {_fmt(row['bound_mean_capped_mm'])} "
            f"| {_fmt(row['bound_known_depth_median_mm'])} | {row['peak_voltage_v']:.2f} "
            f"| {row['electrical_limit_v']:.2f} | {'yes' if row['compliant'] else '**no**'} |{inversion_cell}{learned_cell} {'**yes**' if front[k] else ''} |"
        )
    lines += _comparison(frame, learned, inverted, study.criterion)
    lines += [
        "",
        "## Maps",
        "",
        "Every row with its parameters: `candidates.parquet`; each candidate's map: `maps/<candidate_id>.parquet` "
        "and the PNG linked here.",
        "",
        *(
            f"- [{r['nx']} x {r['ny']} {r['placement']} {r['electrodes']}](maps/{r['candidate_id']}.png)"
            for _, r in frame.iterrows()
        ),
        "",
    ]
    # `design validate` writes its section into this report; a study re-run (or resumed) after it keeps it
    kept = existing_section(out_dir / "report.md")
    if kept is not None:
        lines += [kept.rstrip("\n"), ""]
    write_bytes_durably(out_dir / "report.md", "\n".join(lines).encode())

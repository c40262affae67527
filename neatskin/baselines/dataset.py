"""Loading a campaign dataset for the baselines: checks, flag policy, arrays, layout and physical limit.

Every refusal is one DataError naming the file, the column and the fix: a missing position
or pair column, a NaN or infinite value, no presses left after dropping flagged ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from neatskin.errors import ConfigError, DataError

PHYSICAL_LIMIT_NAME = "physical_limit.parquet"
FLAG_POLICIES = ("drop", "keep", "refuse")


@dataclass(frozen=True)
class BaselineData:
    """Arrays the baselines learn from, with where they came from."""

    source: str
    X: np.ndarray  # (n, pairs) resistance changes, ohm
    y: np.ndarray  # (n, 2) press positions, mm
    groups: np.ndarray  # (n,) position groups (campaign-qualified in merged datasets)
    pair_columns: tuple[str, ...]
    n_flagged_dropped: int
    layout: object | None  # neatskin.layout.Layout when the manifest names one
    physical_limit: pd.DataFrame | None  # position_id, x_mm, y_mm, crb_mm[, crb_nuisance_mm]
    skin_fidelity: str | None = None  # the simulated skin's fidelity (dry runs), from the manifest
    probe_radius_mm: float | None = None  # from the manifest's rig description, when it gives one


def _pair_sort_key(name: str) -> tuple[int, int]:
    _, _, i, j = name.split("_")
    return int(i), int(j)


def _load_layout(folder: Path, metadata: dict):
    """The layout the manifest (or file metadata) names, or None when none is named or found."""
    from neatskin.layout import load_layout

    path = None
    try:
        from neatskin.datasets.manifest import read_manifest, resolve_manifest_path

        path = resolve_manifest_path(folder, read_manifest(folder), "layout")
    except (DataError, ImportError):
        ref = metadata.get("layout")
        if isinstance(ref, dict):
            ref = ref.get("path")
        path = Path(ref) if isinstance(ref, str) else None
    if path is None or not Path(path).is_file():
        return None
    try:
        return load_layout(path)
    except ConfigError:
        return None


def _rig_skin(folder: Path) -> dict:
    """The manifest's rig.skin block (fidelity, probe radius of a dry run), or {}."""
    import json

    path = folder / "manifest.json"
    if not path.is_file():
        return {}
    try:
        skin = json.loads(path.read_text(encoding="utf-8")).get("rig", {}).get("skin", {})
    except (ValueError, AttributeError):
        return {}
    return skin if isinstance(skin, dict) else {}


def check_table(df: pd.DataFrame, source: str, expected_pairs: list[str] | None = None) -> list[str]:
    """The dR pair columns to learn from, after refusing missing columns and non-finite values."""
    for column in ("x_mm", "y_mm", "position_id"):
        if column not in df.columns:
            raise DataError(
                f"missing column {column!r}",
                file=source,
                field=column,
                fix="the baselines need x_mm, y_mm and position_id per press; re-export the dataset",
            )
    found = sorted((c for c in df.columns if c.startswith("dR_ohm_")), key=_pair_sort_key)
    wanted = expected_pairs or found
    if not wanted:
        raise DataError(
            "no dR_ohm_<i>_<j> pair columns",
            file=source,
            field="dR_ohm_*",
            fix="the dataset must hold one resistance-change column per electrode pair",
        )
    missing = [c for c in wanted if c not in df.columns]
    if missing:
        raise DataError(
            f"missing pair column {missing[0]!r} ({len(missing)} of {len(wanted)} missing)",
            file=source,
            field=missing[0],
            fix="every electrode pair of the layout needs its dR_ohm column; re-run or re-export the campaign",
        )
    for column in ("x_mm", "y_mm", *wanted):
        values = pd.to_numeric(df[column], errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            rows = df.index[bad]
            ids = df["press_id"].to_numpy()[bad][:5].tolist() if "press_id" in df.columns else rows[:5].tolist()
            raise DataError(
                f"{int(bad.sum())} NaN or infinite values (press_id {ids})",
                file=source,
                field=column,
                fix="flag those presses (they are dropped by default) or drop them with the dataset tools",
            )
    return wanted


def load_baseline_data(dataset: str | Path, flagged: str = "drop") -> BaselineData:
    """Read a campaign folder (or .parquet file, or merged dataset) into checked arrays."""
    from neatskin.datasets.reader import read_presses

    if flagged not in FLAG_POLICIES:
        raise DataError(f"unknown flag policy {flagged!r}", field="flagged", fix=f"use one of {FLAG_POLICIES}")
    path = Path(dataset)
    df = read_presses(path)
    source = str(path)
    metadata = df.attrs.get("neatskin", {}) or {}
    folder = path if path.is_dir() else path.parent
    layout = _load_layout(folder, metadata)
    expected = None
    if layout is not None:
        expected = [f"dR_ohm_{p.i}_{p.j}" for p in layout.pairs]
    dropped = 0
    if "flags" in df.columns:
        is_flagged = np.array([len(f) > 0 if f is not None else False for f in df["flags"]], dtype=bool)
        if is_flagged.any() and flagged == "refuse":
            raise DataError(
                f"{int(is_flagged.sum())} flagged presses",
                file=source,
                field="flags",
                fix="drop them (the default, flagged='drop') or keep them explicitly",
            )
        if flagged == "drop":
            df = df[~is_flagged]
            dropped = int(is_flagged.sum())
    if len(df) == 0:
        raise DataError(
            "no presses left to learn from" + (f" after dropping {dropped} flagged" if dropped else ""),
            file=source,
            field="flags",
            fix="record presses without flags, or pass flagged='keep'",
        )
    pairs = check_table(df, source, expected)
    groups = df["position_id"].to_numpy()
    if "campaign" in df.columns and df["campaign"].nunique() > 1:  # merged: ids repeat across campaigns
        groups = pd.factorize(df["campaign"].astype(str) + "/" + df["position_id"].astype(str))[0]
    limit = None
    limit_path = folder / PHYSICAL_LIMIT_NAME
    if limit_path.is_file():
        limit = pd.read_parquet(limit_path)
        if "crb_mm" not in limit.columns:
            raise DataError(
                "missing column 'crb_mm'",
                file=str(limit_path),
                field="crb_mm",
                fix="write position_id, x_mm, y_mm, crb_mm (see cramer_rao_bound_mm)",
            )
    skin = _rig_skin(folder)
    radius = skin.get("probe_radius_mm")
    return BaselineData(
        source=source,
        X=df[pairs].to_numpy(dtype=np.float64),
        y=df[["x_mm", "y_mm"]].to_numpy(dtype=np.float64),
        groups=np.asarray(groups, dtype=np.int64),
        pair_columns=tuple(pairs),
        n_flagged_dropped=dropped,
        layout=layout,
        physical_limit=limit,
        skin_fidelity=skin.get("fidelity") if isinstance(skin.get("fidelity"), str) else None,
        probe_radius_mm=float(radius) if isinstance(radius, (int, float)) else None,
    )

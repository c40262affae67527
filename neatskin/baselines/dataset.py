"""Loading a campaign dataset for the baselines: checks, flag policy, arrays, layout and physical limit.

Every refusal is one DataError naming the file, the column and the fix: a missing position
or pair column, a NaN or infinite value, no presses left after dropping flagged ones.

A press that cut a pair off (its electrodes' every path through a shut channel: the galvanostat at its
compliance, the current collapsed, the row's R and dR +inf with `open_circuit:<pair>` and `clipped:<pair>`
flags) is information, not a fault: under the default policy "saturate" it is kept, each infinite dR
replaced by the pair's saturation value (SATURATION_FACTOR x the largest finite |dR| of that pair column
in the dataset: beyond every change the pair measured, so the learners read "cut" as "more than any
pinch"), and the row's flags stay in the dataset. Every other flagged press is dropped, as under "drop".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from neatskin.errors import ConfigError, DataError

PHYSICAL_LIMIT_NAME = "physical_limit.parquet"
_KEY_COLUMNS = ("campaign", "press_id", "position_id", "x_mm", "y_mm", "flags")
FLAG_POLICIES = ("saturate", "drop", "keep", "refuse")
SATURATION_FACTOR = 2.0  # a cut pair's dR, as a multiple of the largest finite |dR| its column measured
CUT_FLAGS = ("open_circuit:", "clipped:")  # the flags a cut pair leaves on its row (acquisition/demod.py)


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
    n_saturated: int = 0  # presses kept with a cut pair, its infinite dR set to the saturation value
    saturation_ohm: tuple[float, ...] = ()  # per pair column, the value a cut pair's dR was given ("saturate")
    # a dry run's scene, from the manifest (None for a real rig's campaign or an older manifest): its preset, its
    # pinch ("fe-kernel" or "parametric") and its probe placement error, so the report can say what was fitted
    scene_preset: str | None = None
    deformation: str | None = None
    placement_error_mm: float | None = None


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
    """The manifest's rig.skin block (fidelity, probe radius, preset, placement error of a dry run), with the
    protocol's scene `deformation` when the block has none, or {}."""
    import json

    path = folder / "manifest.json"
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        skin = manifest.get("rig", {}).get("skin", {})
        scene = manifest.get("protocol_as_run", {}).get("scene", {})
    except (OSError, ValueError, AttributeError):  # none, unreadable (a folder, no permission) or not JSON: no scene
        return {}
    if not isinstance(skin, dict):
        return {}
    if isinstance(scene, dict) and "deformation" not in skin:
        skin = {**skin, "deformation": scene.get("deformation")}
    return skin


def check_table(df: pd.DataFrame, source: str, expected_pairs: list[str] | None = None) -> list[str]:
    """The dR pair columns to learn from, after refusing missing columns and non-finite values."""
    ids = df["press_id"].to_numpy() if "press_id" in df.columns else df.index.to_numpy()
    return _checked_pairs(list(df.columns), lambda c: df[c].to_numpy(), ids, source, expected_pairs)


def _checked_pairs(
    names: list[str],
    values_of: Callable[[str], np.ndarray],
    press_ids: np.ndarray,
    source: str,
    expected_pairs: list[str] | None,
) -> list[str]:
    for column in ("x_mm", "y_mm", "position_id"):
        if column not in names:
            raise DataError(
                f"missing column {column!r}",
                file=source,
                field=column,
                fix="the baselines need x_mm, y_mm and position_id per press; re-export the dataset",
            )
    found = sorted((c for c in names if c.startswith("dR_ohm_")), key=_pair_sort_key)
    wanted = expected_pairs or found
    if not wanted:
        raise DataError(
            "no dR_ohm_<i>_<j> pair columns",
            file=source,
            field="dR_ohm_*",
            fix="the dataset must hold one resistance-change column per electrode pair",
        )
    missing = [c for c in wanted if c not in names]
    if missing:
        raise DataError(
            f"missing pair column {missing[0]!r} ({len(missing)} of {len(wanted)} missing)",
            file=source,
            field=missing[0],
            fix="every electrode pair of the layout needs its dR_ohm column; re-run or re-export the campaign",
        )
    for column in ("x_mm", "y_mm", *wanted):
        values = _as_float(values_of(column))
        bad = ~np.isfinite(values)
        if bad.any():
            ids = press_ids[bad][:5].tolist()
            raise DataError(
                f"{int(bad.sum())} NaN or infinite values (press_id {ids})",
                file=source,
                field=column,
                fix="flag those presses (they are dropped by default) or drop them with the dataset tools",
            )
    return wanted


def _as_float(values: np.ndarray) -> np.ndarray:
    """float64 values; anything that is not a number becomes NaN (and is refused by the caller)."""
    if values.dtype.kind == "f":
        return values.astype(np.float64, copy=False)
    return pd.to_numeric(pd.Series(values), errors="coerce").to_numpy(dtype=float)


def _read_columns(path: Path) -> tuple[pa.Table, dict]:
    """The presses' key, flag and dR columns only (the baselines never look at R_ohm, timestamps or FSR
    times: a third of the bytes), deduplicated by press id as read_presses does, and the file metadata."""
    from neatskin.datasets.reader import press_files
    from neatskin.datasets.schema import decode_metadata
    from neatskin.datasets.tables import unreadable_presses
    from neatskin.datasets.writer import deduplicate_sorted

    files = press_files(path)
    tables = []
    try:
        schema = pq.read_schema(files[0])
        wanted = [n for n in schema.names if n in _KEY_COLUMNS or n.startswith("dR_ohm_")]
        for file in files:  # row group by row group: a whole-file read holds its decode buffers twice
            handle = pq.ParquetFile(file, page_checksum_verification=True)
            columns = [n for n in wanted if n in handle.schema_arrow.names]
            for group in range(handle.metadata.num_row_groups):
                tables.append(handle.read_row_group(group, columns=columns, use_threads=False))
    except (OSError, pa.ArrowException) as exc:
        raise unreadable_presses(exc, path) from exc
    if not tables:
        tables.append(schema.empty_table().select(wanted))
    table = pa.concat_tables([t.replace_schema_metadata(None) for t in tables], promote_options="permissive")
    if "press_id" in table.column_names:
        ids = table.column("press_id").to_numpy()
        if not (ids.size < 2 or bool(np.all(ids[1:] > ids[:-1]))):  # sorted and unique already: no copy
            table = deduplicate_sorted(table)
    return table, decode_metadata(schema.metadata)


def _flagged(table: pa.Table) -> np.ndarray:
    if "flags" not in table.column_names:
        return np.zeros(table.num_rows, dtype=bool)
    lengths = pc.fill_null(pc.list_value_length(table.column("flags")), 0)
    return pc.greater(lengths, 0).to_numpy(zero_copy_only=False)


def _cut_only(table: pa.Table, is_flagged: np.ndarray) -> np.ndarray:
    """The flagged presses whose every flag is a cut pair's (open circuit or clipping on a pair)."""
    flags = table.column("flags").to_pylist() if "flags" in table.column_names else [None] * table.num_rows
    return np.array(
        [bool(f) and all(str(x).startswith(CUT_FLAGS) for x in f) if g else False for f, g in zip(flags, is_flagged)],
        dtype=bool,
    )


def saturate(X: np.ndarray, factor: float = SATURATION_FACTOR) -> tuple[np.ndarray, np.ndarray, int]:
    """X with every +-inf or NaN dR set to its column's saturation value (factor x the column's largest finite
    |dR|; a column with no finite value takes the largest over all columns), that value per column, and the
    number of rows changed. Pure."""
    finite = np.isfinite(X)
    peak = np.where(finite, np.abs(X), 0.0).max(axis=0) if X.size else np.zeros(X.shape[1])
    overall = float(peak.max()) if peak.size and peak.max() > 0 else 1.0
    value = factor * np.where(finite.any(axis=0) & (peak > 0), peak, overall)
    out = np.where(finite, X, value[None, :])
    return out, value, int((~finite).any(axis=1).sum())


def load_baseline_data(dataset: str | Path, flagged: str = "saturate") -> BaselineData:
    """Read a campaign folder (or .parquet file, or merged dataset) into checked arrays: only the columns
    the baselines use, in float64 (exactly the stored values)."""
    if flagged not in FLAG_POLICIES:
        raise DataError(f"unknown flag policy {flagged!r}", field="flagged", fix=f"use one of {FLAG_POLICIES}")
    path = Path(dataset)
    table, metadata = _read_columns(path)
    source = str(path)
    folder = path if path.is_dir() else path.parent
    layout = _load_layout(folder, metadata)
    expected = None
    if layout is not None:
        expected = [f"dR_ohm_{p.i}_{p.j}" for p in layout.pairs]
    dropped = 0
    is_flagged = _flagged(table)
    if is_flagged.any() and flagged == "refuse":
        raise DataError(
            f"{int(is_flagged.sum())} flagged presses",
            file=source,
            field="flags",
            fix="drop them (the default, flagged='drop') or keep them explicitly",
            cli_fix=f"drop them (the default, --flagged drop) or keep them: neatskin baselines {source} --flagged keep",
        )
    if flagged == "saturate" and is_flagged.any():
        is_flagged = is_flagged & ~_cut_only(table, is_flagged)  # a cut pair stays, as information
    if flagged in ("drop", "saturate") and is_flagged.any():
        table = table.filter(pa.array(~is_flagged))
        dropped = int(is_flagged.sum())
    if table.num_rows == 0:
        raise DataError(
            "no presses left to learn from" + (f" after dropping {dropped} flagged" if dropped else ""),
            file=source,
            field="flags",
            fix="record presses without flags, or pass flagged='keep'",
            cli_fix=f"record presses without flags, or keep them: neatskin baselines {source} --flagged keep",
        )

    def values_of(column: str) -> np.ndarray:
        return table.column(column).to_numpy(zero_copy_only=False)

    ids = values_of("press_id") if "press_id" in table.column_names else np.arange(table.num_rows)
    n_saturated, saturation = 0, {}
    if flagged == "saturate":  # a cut pair's +inf dR becomes its column's saturation value before the checks
        found = sorted((c for c in table.column_names if c.startswith("dR_ohm_")), key=_pair_sort_key)
        raw = np.column_stack([_as_float(values_of(c)) for c in found]) if found else np.empty((table.num_rows, 0))
        inf = np.isinf(raw)  # a NaN (nothing measured) is not saturated: it is still refused below
        sat, value, n_saturated = saturate(np.where(inf, np.inf, np.where(np.isnan(raw), 0.0, raw)))
        fixed = np.where(inf, sat, raw)
        columns = {c: fixed[:, k] for k, c in enumerate(found)}
        saturation = {c: float(value[k]) for k, c in enumerate(found)}

        def values_of(column: str) -> np.ndarray:  # noqa: F811
            return columns[column] if column in columns else table.column(column).to_numpy(zero_copy_only=False)

    pairs = _checked_pairs(table.column_names, values_of, ids, source, expected)
    X = np.empty((table.num_rows, len(pairs)), dtype=np.float64)  # column by column: no second full table
    for k, column in enumerate(pairs):
        X[:, k] = _as_float(values_of(column))
    y = np.column_stack([_as_float(values_of("x_mm")), _as_float(values_of("y_mm"))])
    groups = values_of("position_id")
    merged = "merged_from" in metadata  # `dataset merge` made position ids physical across its campaigns
    if not merged and "campaign" in table.column_names:
        campaigns = table.column("campaign").to_pandas()
        if campaigns.nunique() > 1:  # concatenated campaigns: their position ids repeat
            groups = pd.factorize(campaigns.astype(str) + "/" + pd.Series(groups).astype(str))[0]
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
        for column in limit.columns:  # a bound is a number or +inf (unobservable), never NaN: the report pools them
            values = limit[column]
            if pd.api.types.is_numeric_dtype(values) and values.isna().any():
                where = limit.loc[values.isna(), "position_id"].tolist()[:5] if "position_id" in limit else []
                raise DataError(
                    f"{int(values.isna().sum())} NaN values" + (f" (position_id {where})" if where else ""),
                    file=str(limit_path),
                    field=column,
                    fix="delete the file and write it again with `neatskin campaign finish RUN` (a dry run's), or "
                    "leave it deleted (the report then has no bound)",
                )
    skin = _rig_skin(folder)
    radius, placement = skin.get("probe_radius_mm"), skin.get("placement_error_mm")
    return BaselineData(
        source=source,
        X=X,
        y=y,
        groups=np.asarray(groups, dtype=np.int64),
        pair_columns=tuple(pairs),
        n_flagged_dropped=dropped,
        layout=layout,
        physical_limit=limit,
        skin_fidelity=_text(skin.get("fidelity")),
        probe_radius_mm=float(radius) if isinstance(radius, (int, float)) else None,
        n_saturated=n_saturated,
        saturation_ohm=tuple(saturation[c] for c in pairs if c in saturation),
        scene_preset=_text(skin.get("preset")),
        deformation=_text(skin.get("deformation")),
        placement_error_mm=float(placement) if isinstance(placement, (int, float)) else None,
    )


def _text(value: object) -> str | None:
    return value if isinstance(value, str) else None

"""Curation of finished campaigns: describe, merge (re-keyed, provenance kept; in merging.py), split by position,
export.

Every output is a folder (or file) that the reader, the validator and tools without this toolkit read
like a campaign: presses.parquet with `neatskin.` metadata, plus manifest.json for folders.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from neatskin.datasets.curation import (
    campaign_status,
    copy_inputs,
    empty_output,
    flagged_mask,
    manifest_or_empty,
    source_manifest,
)
from neatskin.datasets.durable import write_bytes_durably
from neatskin.datasets.manifest import create_manifest, utc_now_iso
from neatskin.datasets.merging import POSITION_TOLERANCE_MM, merge  # noqa: F401 (curate.merge is the API)
from neatskin.datasets.paths import CONSOLIDATED_NAME, press_parts, waveform_parts
from neatskin.datasets.reader import read_press_table
from neatskin.datasets.schema import decode_metadata, encode_metadata
from neatskin.datasets.values import refuse_bad_values
from neatskin.datasets.writer import write_table_durably
from neatskin.errors import DataError

EXPORT_FORMATS = ("parquet", "csv")
_SUFFIX_FORMATS = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv"}


def export_format(out: str | os.PathLike, format: str | None = None) -> str:
    """The export format: the one named, else the one the output's suffix names (.parquet, .pq, .csv);
    any other suffix is an error rather than a parquet file under a misleading name."""
    if format is not None:
        if format not in EXPORT_FORMATS:
            raise DataError(f"unknown export format {format!r}", field="format", fix=f"use one of {EXPORT_FORMATS}")
        return format
    suffix = Path(out).suffix.lower()
    if suffix not in _SUFFIX_FORMATS:
        raise DataError(
            f"cannot tell the export format from the suffix {suffix or '(none)'!r}",
            file=str(out),
            field="--format",
            fix="name the file .parquet or .csv, or pass --format parquet|csv",
        )
    return _SUFFIX_FORMATS[suffix]


def _write_campaign(out: Path, table: pa.Table, metadata: dict[str, Any], manifest: dict[str, Any]) -> Path:
    table = table.replace_schema_metadata(encode_metadata(metadata))
    write_table_durably(out / CONSOLIDATED_NAME, table)
    n = table.num_rows
    counts = {"planned": n, "completed": n, "flagged": int(flagged_mask(table).sum())}
    create_manifest(out, **{"status": "complete", "finished_at": utc_now_iso(), "counts": counts, **manifest})
    return out


# ---- describe ------------------------------------------------------------------------------------


def describe(path: str | os.PathLike) -> dict[str, Any]:
    """A summary of a dataset: presses, positions, repeats, pairs, flags, ranges, timing, manifest, files."""
    path = Path(path)
    manifest = manifest_or_empty(path)
    try:
        table = read_press_table(path)
    except DataError:
        if not manifest or (path / CONSOLIDATED_NAME).exists() or press_parts(path):  # damaged presses: refused
            raise
        return {  # a campaign that has not finished a press yet: its state is still worth telling
            "path": str(path),
            "campaigns": [manifest.get("campaign")],
            "presses": 0,
            "status": campaign_status(path, manifest),
            "seed": manifest.get("seed"),
            "counts": manifest.get("counts"),
        }
    df = table.drop_columns([c for c in table.column_names if c.startswith("R_ohm_")]).to_pandas()
    meta = decode_metadata(table.schema.metadata)
    per_position = df.groupby("position_id").size()
    dr_cols = [c for c in df.columns if c.startswith("dR_ohm_")]
    flags = pd.Series([f for fl in df["flags"] for f in fl], dtype=object).value_counts()
    return {
        "path": str(path),
        "campaigns": sorted(df["campaign"].unique().tolist()),
        "presses": int(len(df)),
        "positions": int(per_position.size),
        "repeats_per_position": {"min": int(per_position.min()), "max": int(per_position.max())} if len(df) else {},
        "pairs": len(dr_cols),
        "flagged_presses": int(sum(len(f) > 0 for f in df["flags"])),
        "flags": {str(k): int(v) for k, v in flags.items()},
        "x_mm": [float(df["x_mm"].min()), float(df["x_mm"].max())] if len(df) else [],
        "y_mm": [float(df["y_mm"].min()), float(df["y_mm"].max())] if len(df) else [],
        "depth_mm": sorted(float(d) for d in df["depth_mm"].unique()),
        "started_at": str(df["started_at"].min()) if len(df) else None,
        "finished_at": str(df["finished_at"].max()) if len(df) else None,
        "most_sensitive_pairs": most_sensitive_pairs(df[dr_cols]),
        "status": campaign_status(path, manifest) if manifest else None,
        "seed": manifest.get("seed", meta.get("seed")),
        "layout": manifest.get("layout", meta.get("layout")),
        "software_version": meta.get("software_version"),
        "files": {
            "consolidated": (path / CONSOLIDATED_NAME).is_file() if path.is_dir() else True,
            "press_parts": len(press_parts(path)) if path.is_dir() else 0,
            "waveform_parts": len(waveform_parts(path)) if path.is_dir() else 0,
        },
    }


SENSITIVITY_MEASURE = "mean |dR| (ohm) over the presses that did not cut the pair off"


def most_sensitive_pairs(dr: pd.DataFrame, count: int = 3) -> dict[str, Any]:
    """The `count` pairs of the largest mean |dR| over the presses where the pair's dR is finite, as
    {"by": what it ranks by, "pairs": {"i-j": mean |dR| ohm}}. A pair cut off by a pinched channel has dR = +inf
    on that press (its open_circuit flag says so): over all presses every pair ever cut would rank inf (or nan)
    and tie, and the ranking would be the column order; a pair cut on every press has no value and no rank."""
    finite = dr.where(np.isfinite(dr.to_numpy(dtype=float)))
    mean_abs = finite.abs().mean().dropna().sort_values(ascending=False, kind="stable")
    top = {str(c).removeprefix("dR_ohm_").replace("_", "-"): round(float(v), 3) for c, v in mean_abs[:count].items()}
    return {"by": SENSITIVITY_MEASURE, "pairs": top}


def format_description(info: dict[str, Any]) -> str:
    width = max(len(k) for k in info)
    lines = []
    for key, value in info.items():
        text = json.dumps(value, default=str) if isinstance(value, (dict, list)) else str(value)
        lines.append(f"{key:<{width}}  {text}")
    return "\n".join(lines)


# ---- split ---------------------------------------------------------------------------------------


def split_positions(position_ids: np.ndarray, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique position ids -> (train ids, test ids), a seeded shuffle; the test share is test_fraction of the
    positions (at least one in each set)."""
    unique = np.unique(position_ids)
    if not 0.0 < test_fraction < 1.0:
        raise DataError(
            f"test_fraction must be between 0 and 1, got {test_fraction}", field="test_fraction", fix="use e.g. 0.2"
        )
    if unique.size < 2:
        raise DataError(
            f"a split by position needs at least 2 positions, the data has {unique.size}",
            field="position_id",
            fix="press more positions",
        )
    n_test = int(np.clip(round(test_fraction * unique.size), 1, unique.size - 1))
    order = np.random.default_rng(seed).permutation(unique)
    return np.sort(order[n_test:]), np.sort(order[:n_test])


def split(
    path: str | os.PathLike, out: str | os.PathLike, test_fraction: float = 0.2, seed: int = 0
) -> dict[str, Path]:
    """Write out/train and out/test, split BY POSITION: every repeat of a position lands in the same set."""
    path, out = Path(path), Path(out)
    empty_output(out)
    source = source_manifest(path)  # a damaged one stops the split here, before anything is written
    table = read_press_table(path)
    refuse_bad_values(table, str(path), "split")
    meta = decode_metadata(table.schema.metadata)
    positions = table.column("position_id").to_numpy()
    train_ids, test_ids = split_positions(positions, test_fraction, seed)
    result = {}
    for name, ids in (("train", train_ids), ("test", test_ids)):
        part = table.filter(pa.array(np.isin(positions, ids)))
        info = {
            "name": name,
            "source": str(path.resolve()),
            "test_fraction": test_fraction,
            "seed": seed,
            "position_ids": ids.tolist(),
        }
        (out / name).mkdir(parents=True, exist_ok=True)
        manifest = {
            "kind": "split",
            "split": info,
            "campaign": source.get("campaign"),
            **copy_inputs(out / name, [path], [source]),
        }
        if "seed" in source or "seed" in meta:
            manifest["seed"] = source.get("seed", meta.get("seed"))
        result[name] = _write_campaign(out / name, part, {**meta, "split": info}, manifest)
    return result


# ---- export --------------------------------------------------------------------------------------


def export_source_manifest(path: Path) -> dict[str, Any]:
    """The manifest an export scrubs the recorded host with: a campaign folder's own (a damaged one is its DataError,
    before anything is written); for a presses file, its folder's when that reads (the file is what was asked for)."""
    return source_manifest(path) if path.is_dir() else manifest_or_empty(path.parent)


def _without_local_facts(table: pa.Table, manifest: dict[str, Any]) -> pa.Table:
    """The table's metadata without host names and absolute paths (privacy.scrub): an export leaves the lab."""
    from neatskin.datasets.privacy import recorded_hosts, scrub

    hosts = recorded_hosts(manifest)
    return table.replace_schema_metadata(encode_metadata(scrub(decode_metadata(table.schema.metadata), hosts)))


def export(
    path: str | os.PathLike, out: str | os.PathLike, format: str = "parquet", *, drop_flagged: bool = False
) -> Path:
    """One file: parquet (schema metadata kept, host names and local paths removed) or CSV (flags joined by ';', ISO 8601 UTC timestamps, the
    metadata in a `<out>.metadata.json` sidecar since CSV has nowhere to keep it)."""
    if format not in EXPORT_FORMATS:
        raise DataError(f"unknown export format {format!r}", field="format", fix=f"use one of {EXPORT_FORMATS}")
    out = Path(out)
    if out.exists():
        raise DataError("the output file exists", file=str(out), fix="choose a new name; export never overwrites")
    manifest = export_source_manifest(Path(path))
    table = read_press_table(path)
    if drop_flagged:
        table = table.filter(pa.array(~flagged_mask(table)))
    refuse_bad_values(table, str(path), "export")
    table = _without_local_facts(table, manifest)
    if format == "parquet":
        return write_table_durably(out, table)
    df = table.to_pandas()
    df["flags"] = [";".join(f) for f in df["flags"]]
    for col in ("started_at", "finished_at"):
        df[col] = df[col].map(lambda t: t.isoformat())
    out.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_durably(out, df.to_csv(index=False, float_format="%.17g").encode())
    sidecar = out.with_name(out.name + ".metadata.json")
    write_bytes_durably(sidecar, json.dumps(decode_metadata(table.schema.metadata), indent=2, default=str).encode())
    return out

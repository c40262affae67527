"""Curation of finished campaigns: describe, merge (re-keyed, provenance kept), split by position, export.

Every output is a folder (or file) that the reader, the validator and tools without this toolkit read
like a campaign: presses.parquet with `neatskin.` metadata, plus manifest.json for folders.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from neatskin.datasets.durable import write_bytes_durably
from neatskin.datasets.manifest import create_manifest, read_manifest, resolve_manifest_path, utc_now_iso
from neatskin.datasets.paths import CONSOLIDATED_NAME, press_parts, waveform_parts
from neatskin.datasets.reader import read_press_table
from neatskin.datasets.schema import decode_metadata, encode_metadata
from neatskin.datasets.validate import same_file_ref
from neatskin.datasets.writer import write_table_durably
from neatskin.errors import DataError

EXPORT_FORMATS = ("parquet", "csv")


def _manifest_or_empty(folder: Path) -> dict[str, Any]:
    try:
        return read_manifest(folder) if folder.is_dir() else {}
    except DataError:
        return {}


def _absolute_refs(folder: Path, manifest: dict[str, Any]) -> dict[str, Any]:
    """The manifest's layout/wiring/printer references with paths made absolute (they may have been relative
    to the source folder, which the output does not share)."""
    out = {}
    for key in ("layout", "wiring", "printer"):
        path = resolve_manifest_path(folder, manifest, key)
        if path is not None:
            ref = manifest[key] if isinstance(manifest[key], dict) else {}
            out[key] = {**ref, "path": str(path.resolve())}
    return out


def _empty_output(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DataError(
            "the output folder exists and is not empty",
            file=str(out),
            fix="choose a new folder; curation never overwrites data",
        )


def _flagged_mask(table: pa.Table) -> np.ndarray:
    return pc.greater(pc.list_value_length(table.column("flags")), 0).to_numpy(zero_copy_only=False)


def _write_campaign(out: Path, table: pa.Table, metadata: dict[str, Any], manifest: dict[str, Any]) -> Path:
    table = table.replace_schema_metadata(encode_metadata(metadata))
    write_table_durably(out / CONSOLIDATED_NAME, table)
    n = table.num_rows
    counts = {"planned": n, "completed": n, "flagged": int(_flagged_mask(table).sum())}
    create_manifest(out, **{"status": "complete", "finished_at": utc_now_iso(), "counts": counts, **manifest})
    return out


# ---- describe ------------------------------------------------------------------------------------


def describe(path: str | os.PathLike) -> dict[str, Any]:
    """A summary of a dataset: presses, positions, repeats, pairs, flags, ranges, timing, manifest, files."""
    path = Path(path)
    table = read_press_table(path)
    df = table.drop_columns([c for c in table.column_names if c.startswith("R_ohm_")]).to_pandas()
    meta = decode_metadata(table.schema.metadata)
    manifest = _manifest_or_empty(path)
    per_position = df.groupby("position_id").size()
    dr_cols = [c for c in df.columns if c.startswith("dR_ohm_")]
    mean_dr = df[dr_cols].mean()
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
        "most_sensitive_pairs": [
            c.removeprefix("dR_ohm_").replace("_", "-") for c in mean_dr.abs().sort_values(ascending=False).index[:3]
        ],
        "status": manifest.get("status"),
        "seed": manifest.get("seed", meta.get("seed")),
        "layout": manifest.get("layout", meta.get("layout")),
        "software_version": meta.get("software_version"),
        "files": {
            "consolidated": (path / CONSOLIDATED_NAME).is_file() if path.is_dir() else True,
            "press_parts": len(press_parts(path)) if path.is_dir() else 0,
            "waveform_parts": len(waveform_parts(path)) if path.is_dir() else 0,
        },
    }


def format_description(info: dict[str, Any]) -> str:
    width = max(len(k) for k in info)
    lines = []
    for key, value in info.items():
        text = json.dumps(value, default=str) if isinstance(value, (dict, list)) else str(value)
        lines.append(f"{key:<{width}}  {text}")
    return "\n".join(lines)


# ---- merge ---------------------------------------------------------------------------------------


def merge(folders: Sequence[str | os.PathLike], out: str | os.PathLike, *, allow_mixed: bool = False) -> Path:
    """Merge campaigns into one dataset folder. Press ids and position ids are re-keyed: source k's ids are
    shifted by the sum of (max id + 1) of the sources before it (offsets recorded under `merged_from`).
    Refuses different pair sets always, and different layouts or wirings unless allow_mixed."""
    sources = [Path(f) for f in folders]
    out = Path(out)
    if len(sources) < 2:
        raise DataError("merge needs at least two campaign folders", field="folders", fix="name two or more")
    _empty_output(out)
    loaded = []
    for folder in sources:
        table = read_press_table(folder)
        loaded.append((folder, table, decode_metadata(table.schema.metadata), _manifest_or_empty(folder)))
    first_folder, first_table, first_meta, first_manifest = loaded[0]
    for folder, table, meta, manifest in loaded[1:]:
        if table.schema.names != first_table.schema.names:
            raise DataError(
                f"its electrode pairs differ from those of {first_folder}",
                file=str(folder),
                field="pairs",
                fix="only campaigns measuring the same pairs can share one table",
            )
        for key in ("layout", "wiring"):
            a = first_manifest.get(key, first_meta.get(key))
            b = manifest.get(key, meta.get(key))
            if not allow_mixed and a is not None and b is not None and not same_file_ref(a, b):
                raise DataError(
                    f"{key} {b!r} differs from {a!r} of {first_folder}",
                    file=str(folder),
                    field=key,
                    fix="merge only campaigns on one skin and wiring, or pass --allow-mixed",
                )
    tables, provenance = [], []
    press_offset = position_offset = 0
    for folder, table, meta, manifest in loaded:
        ids = table.column("press_id")
        pos = table.column("position_id")
        shifted = table.set_column(
            table.schema.get_field_index("press_id"),
            table.schema.field("press_id"),
            pc.add(ids, pa.scalar(press_offset, pa.int64())),
        )
        shifted = shifted.set_column(
            shifted.schema.get_field_index("position_id"),
            shifted.schema.field("position_id"),
            pc.add(pos, pa.scalar(position_offset, pa.int32())),
        )
        tables.append(shifted.replace_schema_metadata(None))
        provenance.append(
            {
                "folder": str(folder.resolve()),
                "presses": table.num_rows,
                "press_id_offset": press_offset,
                "position_id_offset": position_offset,
                "metadata": {k: v for k, v in meta.items() if k != "pairs"},
                "manifest": manifest,
            }
        )
        if table.num_rows:
            press_offset += int(pc.max(ids).as_py()) + 1
            position_offset += int(pc.max(pos).as_py()) + 1
    merged = pa.concat_tables(tables)
    refs = _absolute_refs(first_folder, first_manifest)
    metadata = {
        "pairs": first_meta.get("pairs"),
        "software_version": first_meta.get("software_version"),
        "merged_from": provenance,
        **{k: v for k, v in refs.items()},
    }
    manifest = {"kind": "merge", "allow_mixed": allow_mixed, "sources": [p["folder"] for p in provenance], **refs}
    seeds = {json.dumps(m.get("seed", meta.get("seed"))) for _, _, meta, m in loaded}
    if len(seeds) == 1:
        metadata["seed"] = manifest["seed"] = json.loads(seeds.pop())
    return _write_campaign(out, merged, metadata, manifest)


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
    _empty_output(out)
    table = read_press_table(path)
    meta = decode_metadata(table.schema.metadata)
    source_manifest = _manifest_or_empty(path)
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
        manifest = {
            "kind": "split",
            "split": info,
            "campaign": source_manifest.get("campaign"),
            **_absolute_refs(path, source_manifest),
        }
        if "seed" in source_manifest or "seed" in meta:
            manifest["seed"] = source_manifest.get("seed", meta.get("seed"))
        result[name] = _write_campaign(out / name, part, {**meta, "split": info}, manifest)
    return result


# ---- export --------------------------------------------------------------------------------------


def export(
    path: str | os.PathLike, out: str | os.PathLike, format: str = "parquet", *, drop_flagged: bool = False
) -> Path:
    """One file: parquet (schema metadata kept) or CSV (flags joined by ';', ISO 8601 UTC timestamps, the
    metadata in a `<out>.metadata.json` sidecar since CSV has nowhere to keep it)."""
    if format not in EXPORT_FORMATS:
        raise DataError(f"unknown export format {format!r}", field="format", fix=f"use one of {EXPORT_FORMATS}")
    out = Path(out)
    if out.exists():
        raise DataError("the output file exists", file=str(out), fix="choose a new name; export never overwrites")
    table = read_press_table(path)
    if drop_flagged:
        table = table.filter(pa.array(~_flagged_mask(table)))
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

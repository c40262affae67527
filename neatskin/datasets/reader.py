"""Reading campaign datasets back: presses (from the consolidated file and/or the durable parts,
deduplicated by press_id, temp files ignored), their metadata, raw waveforms, and the (X, y, groups)
arrays the baselines learn from.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from neatskin.datasets.paths import CONSOLIDATED_NAME, MANIFEST_NAME, WAVEFORMS_DIR, part_press_id, press_parts
from neatskin.datasets.schema import decode_metadata, parse_pair_column
from neatskin.datasets.tables import deduplicate_sorted, read_tables, refuse_missing_columns, unreadable_presses
from neatskin.errors import DataError
from neatskin.layout import ElectrodePair

ACCEPTED = "a campaign folder (written by `neatskin campaign run`) or its presses.parquet"
PARQUET_MAGIC = b"PAR1"  # the first (and last) four bytes of every parquet file


def press_files(path: str | os.PathLike) -> list[Path]:
    """The parquet files holding a dataset's presses: a .parquet file itself, a campaign folder's
    presses.parquet and presses/part-*.parquet, or the part-*.parquet files of a folder. Anything else (a CSV
    export, an empty file, a folder that is no campaign) is one DataError naming it, what is accepted and the fix."""
    path = Path(path)
    if path.is_file():
        refused = not_a_press_file(path)
        if refused is not None:
            raise refused
        return [path]
    if not path.is_dir():
        raise DataError("no such dataset file or folder", file=str(path), fix=f"give {ACCEPTED}")
    files = [path / CONSOLIDATED_NAME] if (path / CONSOLIDATED_NAME).is_file() else []
    files += list(press_parts(path).values())
    if not files:
        files = sorted(p for p in path.iterdir() if part_press_id(p) is not None)
    if not files:
        raise _no_presses_in(path)
    return files


def not_a_press_file(path: Path) -> DataError | None:
    """None for a parquet file with a press_id column (or one too damaged to tell: the reader and `validate` say what
    is wrong with it); else the error that says what the file is instead. (A CSV export used to get "Parquet magic
    bytes not found ... the file is corrupted" from `dataset info` and "[pairs]: no electrode pairs given (fix: pass
    layout.pairs)" from `dataset validate`.)"""
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        return DataError(f"cannot read the file: {exc.strerror or exc}", file=str(path), fix="check its permissions")
    fix = f"neatskin reads {ACCEPTED}: give one"
    if head.startswith(PARQUET_MAGIC):
        try:
            schema = pq.read_schema(path)
        except (OSError, pa.ArrowException):
            return None  # damaged: told by the reader (and by validate, file by file)
        # a press table's own metadata (its pairs) with press_id gone is a damaged press table: the reader names
        # the missing column as validate does
        if "press_id" in schema.names or b"neatskin.pairs" in (schema.metadata or {}):
            return None
        what = "a parquet file without a press_id column, not a press table (a campaign's physical_limit.parquet?)"
    elif not head:
        what = "the file is empty (0 bytes), not a press table"
    elif path.name.endswith(".metadata.json"):
        what = "the metadata sidecar of a CSV export, not a press table"
        fix = f"neatskin reads {ACCEPTED}: give the campaign folder the CSV was exported from"
    elif path.name == "manifest.json":
        what, fix = "a campaign's manifest, not its presses", f"give the campaign folder {path.parent}"
    elif path.suffix.lower() in (".csv", ".tsv", ".txt") or (b"," in head.split(b"\n", 1)[0] and _is_text(head)):
        what = "a CSV file, not a press table"
        fix = (
            f"CSV exports are for other tools (pandas, spreadsheets); neatskin reads {ACCEPTED}: give the "
            "campaign folder the CSV was exported from"
        )
    else:
        what = "not a parquet file (it does not begin with the bytes PAR1)"
    return DataError(what, file=str(path), fix=fix)


def _is_text(head: bytes) -> bool:
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _no_presses_in(folder: Path) -> DataError:
    """The error for a folder without presses: a campaign that never finished a press, or no campaign at all."""
    if (folder / MANIFEST_NAME).is_file():
        return DataError(
            "the campaign folder holds no presses (no presses.parquet, no presses/part-*.parquet)",
            file=str(folder),
            fix="check the path; a campaign that never finished a press has no data",
        )
    tables = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".parquet", ".pq") and p.is_file())
    hint = f", or one of the parquet files it holds (e.g. {tables[0]})" if tables else ""
    return DataError(
        "not a campaign folder: no manifest.json, no presses.parquet, no presses/part-*.parquet",
        file=str(folder),
        fix=f"give {ACCEPTED}{hint}",
    )


def read_press_table(path: str | os.PathLike, *, deduplicate: bool = True) -> pa.Table:
    """All presses as one arrow table (sorted by press_id, first copy of a duplicated id kept), with the
    `neatskin.` metadata of the consolidated file (or of the first part). A file that lacks a press column is
    refused (refuse_missing_columns): the others must match the first's columns (read_tables)."""
    files = press_files(path)
    try:
        schema = pq.read_schema(files[0])
        refuse_missing_columns(schema, files[0])
        table = read_tables(files, schema.remove_metadata())
    except (OSError, pa.ArrowException) as exc:
        raise unreadable_presses(exc, path) from exc
    if deduplicate:
        table = deduplicate_sorted(table)
    return table.replace_schema_metadata(schema.metadata)


def read_presses(path: str | os.PathLike, *, deduplicate: bool = True) -> pd.DataFrame:
    """All presses as a DataFrame, one row per press id; `df.attrs['neatskin']` holds the metadata."""
    table = read_press_table(path, deduplicate=deduplicate)
    df = table.to_pandas()
    df.attrs["neatskin"] = decode_metadata(table.schema.metadata)
    return df


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The `neatskin.` key-value metadata (prefix stripped, JSON decoded) of a dataset file or folder."""
    return decode_metadata(pq.read_schema(press_files(path)[0]).metadata)


def read_waveforms(folder: str | os.PathLike, press_ids: Iterable[int] | None = None) -> pd.DataFrame:
    """Raw samples (one row per sample, with position_id from the partition) of the durable presses,
    optionally only `press_ids`; sorted by press_id and sample."""
    root = Path(folder) / WAVEFORMS_DIR
    if not root.is_dir():
        raise DataError(
            "this campaign recorded no waveforms",
            file=str(root),
            fix="set the protocol to record raw waveforms and run the campaign again",
        )
    durable = set(read_press_table(folder).column("press_id").to_pylist())
    wanted = durable if press_ids is None else durable & {int(i) for i in press_ids}
    dataset = pads.dataset(str(root), format="parquet", partitioning="hive")
    table = dataset.to_table(filter=pads.field("press_id").isin(sorted(wanted)))
    return table.to_pandas().sort_values(["press_id", "sample"], kind="stable").reset_index(drop=True)


def pair_labels_from_columns(df: pd.DataFrame) -> tuple[ElectrodePair, ...]:
    """The electrode pairs of a press table, in the order of its dR_ohm_i_j columns."""
    pairs = []
    for name in df.columns:
        parsed = parse_pair_column(str(name))
        if parsed and parsed[0] == "dR":
            pairs.append(parsed[1])
    if not pairs:
        raise DataError(
            "the table has no dR_ohm_i_j columns", field="dR_ohm_*", fix="read the presses with read_presses()"
        )
    return tuple(pairs)


def feature_matrix(df: pd.DataFrame, *, exclude_flagged: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """X (n, pairs) from the dR columns in pair order, y (n, 2) = (x_mm, y_mm), groups (n,) = position_id.

    Use `groups` for grouped splits (GroupKFold, GroupShuffleSplit) so repeats of a position never straddle
    train and test. With exclude_flagged, presses carrying any flag are dropped.
    """
    if exclude_flagged:
        df = df[[len(f) == 0 for f in df["flags"]]]
    pairs = pair_labels_from_columns(df)
    X = df[[f"dR_ohm_{p.i}_{p.j}" for p in pairs]].to_numpy(dtype=np.float64)
    y = df[["x_mm", "y_mm"]].to_numpy(dtype=np.float64)
    groups = df["position_id"].to_numpy(dtype=np.int64)
    return X, y, groups

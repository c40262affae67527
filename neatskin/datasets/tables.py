"""Whole parquet files of a campaign: checksummed reads, the refusal of a press file that lacks a column (the
line `validate` gives), parts concatenated and deduplicated by press id, waveform tables, and a press table
written as one durable file. Pure helpers of the writer, the reader
and the curation tools; the campaign writer itself is neatskin.datasets.writer.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from neatskin.campaignread import read_parquet as read_parquet  # re-exported: the datasets read them here
from neatskin.campaignread import unreadable_presses as unreadable_presses
from neatskin.datasets.durable import read_error, write_durably
from neatskin.datasets.schema import BASE_COLUMNS, decode_metadata, normalise_pairs, pair_columns, parse_pair_column
from neatskin.errors import DataError, Problem

MISSING_COLUMNS_FIX = (
    "rewrite the file with every column of the layout's schema (or validate against the layout the campaign used)"
)


def missing_columns_problem(missing: Sequence[str], file: str) -> Problem:
    """The problem `dataset validate` reports for a press file that lacks columns (and every reader refuses)."""
    return Problem(f"missing column(s): {', '.join(missing)}", file, ", ".join(missing), MISSING_COLUMNS_FIX)


def missing_press_columns(schema: pa.Schema) -> list[str]:
    """The press columns a file's schema lacks: the fixed ones, and R_ohm and dR_ohm of every pair its metadata
    names (metadata gone or damaged: of every pair either kind of pair column names)."""
    try:
        pairs = normalise_pairs(decode_metadata(schema.metadata).get("pairs") or ())
    except (DataError, TypeError, ValueError, IndexError, KeyError):
        found = (parse_pair_column(name) for name in schema.names)
        pairs = tuple(dict.fromkeys(pair for _, pair in filter(None, found)))
    r_cols, dr_cols = pair_columns(pairs)
    return [name for name in (*BASE_COLUMNS, *r_cols, *dr_cols) if name not in schema.names]


def refuse_missing_columns(schema: pa.Schema, file: Path) -> None:
    """One DataError, validate's own, for a press file without a column every reader relies on (a position, a
    key, a pair's dR): refused before anything downstream fails on it or writes a dataset without it."""
    missing = missing_press_columns(schema)
    if missing:
        raise DataError(problems=[missing_columns_problem(missing, str(file))])


def file_sha256(path: Path, restore: str = "restore the file from a backup") -> str:
    """The file's sha256; a file that cannot be read (permission, a folder in its place) is a DataError naming it,
    whose fix ends with `restore` (how to get the file back)."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as exc:
        raise read_error(exc, path, restore) from exc
    return digest.hexdigest()


def read_tables(files: Sequence[Path], schema: pa.Schema) -> pa.Table:
    """Concatenate parquet files of one schema (metadata dropped). Reads file by file: for many one-row parts
    this is twice as fast as a pyarrow dataset scan."""
    tables = []
    for path in files:
        try:
            table = read_parquet(path)
        except (OSError, pa.ArrowException) as exc:
            raise DataError(
                f"cannot read a parquet part: {exc}",
                file=str(path),
                fix="move the damaged file out of the campaign folder, then resume",
            ) from exc
        if not table.schema.equals(schema):
            if table.schema.names != schema.names or table.schema.types != schema.types:
                refuse_missing_columns(pq.read_schema(path), path)  # validate's line for a column it lacks
                raise DataError(
                    "the file's columns differ from the campaign's schema",
                    file=str(path),
                    fix="run `neatskin dataset validate` on the folder for the details",
                )
            table = table.cast(schema)  # only nullability differs
        tables.append(table)
    return pa.concat_tables(tables) if tables else schema.empty_table()


def deduplicate_sorted(table: pa.Table) -> pa.Table:
    """Rows sorted by press_id, the first occurrence of each press id kept."""
    ids = table.column("press_id").to_numpy()
    order = np.argsort(ids, kind="stable")
    _, first = np.unique(ids[order], return_index=True)
    return table.take(pa.array(order[first]))


def waveform_table(press_id: int, waveforms: Mapping[str, np.ndarray]) -> pa.Table:
    """One row per sample: press_id, sample, then each named 1-D signal (all of one length)."""
    arrays = {name: np.asarray(values) for name, values in waveforms.items()}
    lengths = {name: a.shape for name, a in arrays.items()}
    if any(len(shape) != 1 for shape in lengths.values()) or len(set(lengths.values())) != 1:
        raise DataError(
            f"waveforms must be 1-D arrays of one length, got shapes {lengths}",
            field="waveforms",
            fix="pass one 1-D array per signal, sample-aligned (e.g. voltage_v, current_a, fsr_v)",
        )
    reserved = {"press_id", "sample", "position_id"} & set(arrays)
    if reserved:
        raise DataError(f"waveform name(s) {sorted(reserved)} are reserved", field="waveforms", fix="rename the signal")
    n = next(iter(lengths.values()))[0]
    columns = {"press_id": np.full(n, press_id, dtype=np.int64), "sample": np.arange(n, dtype=np.int32)}
    columns.update(arrays)
    return pa.table(columns)


def write_table_durably(path: str | os.PathLike, table: pa.Table, *, fsync: bool = True) -> Path:
    """Write a whole press table (with its metadata) as one parquet file, atomically and durably."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_durably(
        path,
        lambda handle: pq.write_table(table, handle, row_group_size=1 << 16, write_page_checksum=True),
        fsync=fsync,
    )

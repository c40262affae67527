"""One streaming pass over a dataset's press files for validation: schemas, nulls, flags, campaigns, a hash of
every row and the few key columns per row (press id, position, x, y), read row group by row group so that
memory holds one row group of full rows (4,096 in a campaign's or a merge's presses.parquet), never the
whole dataset.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from neatskin.datasets.schema import CUT_PAIR_FLAG_KINDS, OPEN_CIRCUIT_FLAG, parse_pair_column, plausible_range

KEY_COLUMNS = ("press_id", "position_id", "x_mm", "y_mm")


@dataclass
class NullRows:
    """Where one column holds nulls (or NaN): how many rows, in which files (by index), for which press ids."""

    count: int = 0
    files: set[int] = field(default_factory=set)
    press_ids: list[np.ndarray] = field(default_factory=list)
    examples: list[float] = field(default_factory=list)  # a few of the bad values (for non-finite and absurd)


@dataclass
class DatasetScan:
    """What validation needs from the rows, gathered without holding them.

    `keys` has one row per row read (duplicates across files included): press_id, position_id, x_mm, y_mm
    (float, NaN where a file lacks the column), file (index into `files`), row_hash (of every column of the
    expected schema but flags) and flagged."""

    files: list[Path] = field(default_factory=list)  # readable files, in reading order
    schemas: list[pa.Schema] = field(default_factory=list)
    unreadable: list[tuple[Path, str]] = field(default_factory=list)
    keys: pd.DataFrame = field(default_factory=pd.DataFrame)
    nulls: dict[str, NullRows] = field(default_factory=dict)
    nonfinite: dict[str, NullRows] = field(default_factory=dict)  # +-inf (a pair's +inf with its flag is fine)
    implausible: dict[str, NullRows] = field(default_factory=dict)  # finite, outside schema.PLAUSIBLE_RANGES
    flag_counts: Counter = field(default_factory=Counter)
    campaigns: set[str] = field(default_factory=set)
    columns: set[str] = field(default_factory=set)  # every column some readable file has


def read_schema(file: Path) -> pa.Schema:
    """A press file's arrow schema (with its key-value metadata); raises what pyarrow raises."""
    return pq.read_schema(file)


def scan_files(files: Sequence[Path], expected: pa.Schema, nullable: dict[str, bool]) -> DatasetScan:
    """Read every file row group by row group (page checksums verified). A file that fails anywhere counts as
    unreadable as a whole: nothing it held enters the scan, as when it was read in one piece."""
    scan = DatasetScan()
    keys: list[pd.DataFrame] = []
    for file in files:
        part = DatasetScan()
        part_keys: list[pd.DataFrame] = []
        try:
            handle = pq.ParquetFile(file, page_checksum_verification=True)
            schema = handle.schema_arrow
            for group in range(handle.metadata.num_row_groups):  # iter_batches would read ahead: memory grows
                table = handle.read_row_group(group, use_threads=False)
                part_keys.append(_scan_batch(part, table, expected, nullable, len(scan.files)))
            if handle.metadata.num_row_groups == 0:
                part_keys.append(_scan_batch(part, schema.empty_table(), expected, nullable, len(scan.files)))
        except (OSError, pa.ArrowException) as exc:
            scan.unreadable.append((file, str(exc)))
            continue
        scan.files.append(file)
        scan.schemas.append(schema)
        keys.extend(part_keys)
        scan.columns.update(schema.names)
        scan.flag_counts.update(part.flag_counts)
        scan.campaigns.update(part.campaigns)
        for found, into in ((part.nulls, scan.nulls), (part.nonfinite, scan.nonfinite)):
            _add(found, into)
        _add(part.implausible, scan.implausible)
    scan.keys = pd.concat(keys, ignore_index=True) if keys else pd.DataFrame(columns=[*KEY_COLUMNS, "file"])
    return scan


def _add(found: dict[str, NullRows], into: dict[str, NullRows]) -> None:
    for name, rows in found.items():
        total = into.setdefault(name, NullRows())
        total.count += rows.count
        total.files.update(rows.files)
        total.press_ids.extend(rows.press_ids)
        total.examples.extend(rows.examples[: max(0, 3 - len(total.examples))])


def _note(where: dict[str, NullRows], name: str, bad: np.ndarray, values: np.ndarray, ids, file_index: int) -> None:
    rows = where.setdefault(name, NullRows())
    rows.count += int(bad.sum())
    rows.files.add(file_index)
    if ids is not None:
        rows.press_ids.append(ids[bad])
    rows.examples.extend(values[bad][: max(0, 3 - len(rows.examples))].tolist())


def scan_values(scan: DatasetScan, table: pa.Table, want: pa.Field, ids: np.ndarray | None, file_index: int) -> None:
    """Record the column's +-inf (a pair's +inf or dR +-inf with the row's open_circuit flag excepted) and its
    finite values outside the plausible range."""
    values = table.column(want.name).to_numpy(zero_copy_only=False).astype(float)
    inf = np.isinf(values)
    pair = parse_pair_column(want.name)
    if inf.any() and pair is not None and "flags" in table.column_names:
        flag = f"{OPEN_CIRCUIT_FLAG}:{pair[1].label}"
        rows = np.flatnonzero(inf)
        flags = table.column("flags").take(pa.array(rows)).to_pylist()
        allowed = pair[0] == "dR" or values[rows] > 0  # an open circuit is +inf ohm, never -inf
        inf[rows] = ~(allowed & np.array([flag in (f or []) for f in flags], dtype=bool))
    if inf.any():
        _note(scan.nonfinite, want.name, inf, values, ids, file_index)
    span = plausible_range(want.name)
    if span is not None:
        with np.errstate(invalid="ignore"):
            out = np.isfinite(values) & ((values < span[0]) | (values > span[1]))
        if out.any():
            _note(scan.implausible, want.name, out, values, ids, file_index)


def _scan_batch(
    scan: DatasetScan, table: pa.Table, expected: pa.Schema, nullable: dict[str, bool], file_index: int
) -> pd.DataFrame:
    n = table.num_rows
    table = _as_expected_types(table, expected)
    names = set(table.column_names)
    ids = table.column("press_id").to_numpy(zero_copy_only=False).astype(float) if "press_id" in names else None
    for want in expected:
        if want.name in names and pa.types.is_floating(table.column(want.name).type):
            scan_values(scan, table, want, ids, file_index)
        if want.name not in names or nullable.get(want.name, False):
            continue
        column = table.column(want.name)
        floating = pa.types.is_floating(column.type)
        bad = pc.is_null(column, nan_is_null=True) if floating else pc.is_null(column)
        count = pc.sum(bad).as_py() or 0
        if count:
            rows = scan.nulls.setdefault(want.name, NullRows())
            rows.count += count
            rows.files.add(file_index)
            if ids is not None:
                rows.press_ids.append(ids[bad.to_numpy(zero_copy_only=False)])
    keys = pd.DataFrame(
        {
            name: table.column(name).to_numpy(zero_copy_only=False).astype(float)
            if name in names
            else np.full(n, np.nan)
            for name in KEY_COLUMNS
        }
    )
    keys["file"] = np.full(n, file_index, dtype=np.int32)
    keys["row_hash"] = _row_hashes(table, expected)
    keys["flagged"] = np.zeros(n, dtype=bool)
    keys["cut_pairs_only"] = np.zeros(n, dtype=bool)
    flags = table.column("flags") if "flags" in names else None
    if flags is not None and (pa.types.is_list(flags.type) or pa.types.is_large_list(flags.type)):
        flagged = pc.fill_null(pc.greater(pc.list_value_length(flags), 0), False)
        keys["flagged"] = flagged.to_numpy(zero_copy_only=False)
        keys["cut_pairs_only"] = np.zeros(n, dtype=bool)
        if keys["flagged"].any():
            values = pc.list_flatten(flags.filter(flagged))
            scan.flag_counts.update(v for v in values.to_pylist() if v is not None)
            keys["cut_pairs_only"] = cut_pairs_only(flags, keys["flagged"].to_numpy(bool))
    if "campaign" in names:
        scan.campaigns.update(v for v in pc.unique(table.column("campaign")).to_pylist() if v is not None)
    return keys


def _as_expected_types(table: pa.Table, expected: pa.Schema) -> pa.Table:
    """Columns cast to the expected schema's types where the cast keeps the values (string for large_string,
    timestamp units, a list of nulls): rows that hold the same values then hash alike."""
    want = {f.name: f.type for f in expected}
    for k, name in enumerate(table.column_names):
        target = want.get(name)
        if target is None or table.schema.field(k).type == target:
            continue
        try:
            table = table.set_column(k, pa.field(name, target), table.column(k).cast(target))
        except (pa.ArrowException, ValueError):
            pass  # a column of another type: reported by the schema check
    return table


def _row_hashes(table: pa.Table, expected: pa.Schema) -> np.ndarray:
    """A 64-bit hash per row over the expected columns (flags excluded; a missing column hashes as NaN)."""
    n = table.num_rows
    columns: dict[str, np.ndarray] = {}
    for want in expected:
        if want.name == "flags":
            continue
        if want.name in table.column_names:
            column = table.column(want.name)
            if pa.types.is_list(column.type) or pa.types.is_large_list(column.type):
                columns[want.name] = np.array([repr(v) for v in column.to_pylist()], dtype=object)
            else:
                columns[want.name] = column.to_numpy(zero_copy_only=False)
        else:
            columns[want.name] = np.full(n, np.nan)
    if not columns:
        return np.zeros(n, dtype=np.uint64)
    return pd.util.hash_pandas_object(pd.DataFrame(columns), index=False).to_numpy()


def cut_pairs_only(flags: pa.ChunkedArray, flagged: np.ndarray) -> np.ndarray:
    """Per row: flagged, and every flag it carries says a pair was cut off (`open_circuit:i-j`, with or without
    `clipped:i-j` for the same pair). A pair clipped but still conducting, or a row-level flag, is not."""
    rows = np.flatnonzero(flagged)
    chosen = pc.take(flags, pa.array(rows))
    values = pc.list_flatten(chosen).to_pylist()  # one pass over the flagged rows' flags, not one row at a time
    parents = np.asarray(pc.list_parent_indices(chosen))
    kinds: list[dict[str, set[str]]] = [{} for _ in rows]
    for k, flag in zip(parents.tolist(), values):
        kind, sep, pair = str(flag).partition(":")
        kinds[k].setdefault(kind if sep and pair else "", set()).add(pair)
    out = np.zeros(flagged.shape, dtype=bool)
    for k, row in enumerate(rows):
        cut = kinds[k].get(CUT_PAIR_FLAG_KINDS[0], set())
        out[row] = bool(cut) and set(kinds[k]) <= set(CUT_PAIR_FLAG_KINDS) and kinds[k].get("clipped", set()) <= cut
    return out

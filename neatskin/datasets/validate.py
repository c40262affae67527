"""Dataset validation: every problem in a campaign folder (schema, NaNs, duplicate press ids, positions
outside the layout, flagged presses, manifest consistency), one Problem each, naming file, column and fix.

This module owns the entry point and the checks of the rows (schema and content); the checks of the folder's
files against their records live in `folderchecks`, of the manifest against the data in `manifestchecks`, of
values in `values`. The rows are read once, row group by row group (datasets/scan.py): memory holds one row
group of full rows plus a few key columns per press, so a merged dataset of 280,000 presses validates in
bounded memory.
"""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from neatskin.datasets.folderchecks import integrity_problems, part_ids_valid, unreadable_fix, waveform_problems, where
from neatskin.datasets.manifest import MANIFEST_NAME, read_manifest
from neatskin.datasets.manifestchecks import manifest_layout, manifest_problems, same_file_ref
from neatskin.datasets.reader import ACCEPTED, press_files
from neatskin.datasets.scan import DatasetScan, read_schema, scan_files
from neatskin.datasets.schema import BASE_FIELDS, OPTIONAL_COLUMNS, decode_metadata, parse_pair_column, press_schema
from neatskin.datasets.tables import missing_columns_problem
from neatskin.datasets.values import metadata_layout, value_problems
from neatskin.errors import DataError, Problem
from neatskin.layout import ElectrodePair, Layout

# part_ids_valid and same_file_ref were defined here before the split: importable from here as they were
__all__ = ["check_dataset", "part_ids_valid", "same_file_ref", "validate_dataset"]

_FLOAT_CHECKED = ("x_mm", "y_mm", "depth_mm")


def check_dataset(path: str | os.PathLike, **kwargs: Any) -> None:
    """Raise DataError listing every problem validate_dataset finds."""
    problems = validate_dataset(path, **kwargs)
    if problems:
        raise DataError(problems=problems)


def validate_dataset(
    path: str | os.PathLike,
    *,
    layout: Layout | None = None,
    allow_flagged: bool = False,
    notes: list[str] | None = None,
) -> list[Problem]:
    """Every problem in a campaign folder (or a single press parquet file), one Problem each.

    The layout for the bounds check: `layout`, else the one the manifest names, else the one the files'
    metadata names (found beside the file and checked against its recorded sha256). What could not be checked
    is said in `notes` (when given), never silently skipped."""
    path = Path(path)
    problems: list[Problem] = []
    manifest, manifest_file = None, str(path / MANIFEST_NAME)
    if path.is_dir():
        try:
            manifest = read_manifest(path)
        except DataError as exc:
            problems.extend(exc.problems)
    if layout is None and manifest is not None:
        layout = manifest_layout(path, manifest, manifest_file, problems)
    try:
        files = press_files(path)
    except DataError as exc:
        if path.is_dir() and not (path / MANIFEST_NAME).exists():
            return list(exc.problems)  # "not a campaign folder" says it all: no second line for its missing manifest
        return problems + list(exc.problems)

    try:
        first_schema = next(_readable_schemas(files))
    except StopIteration:
        first_schema = None
    metadata = decode_metadata(first_schema.metadata) if first_schema is not None else {}
    if layout is None and manifest is None:
        layout = metadata_layout(path if path.is_dir() else path.parent, metadata, notes)
    pairs = _expected_pairs(layout, manifest, metadata, first_schema if first_schema is not None else pa.schema([]))
    if not pairs and first_schema is not None:  # a parquet file, but no press table (e.g. physical_limit.parquet)
        return problems + [
            Problem(
                "a parquet file without dR_ohm_i_j columns or recorded pairs: not a press table",
                str(files[0]),
                "dR_ohm_*",
                f"give {ACCEPTED}",
            )
        ]
    expected = press_schema(pairs)
    nullable = {f.name: f.nullable for f in BASE_FIELDS}
    scan = scan_files(files, expected, nullable)
    for file, error in scan.unreadable:
        problems.append(Problem(f"unreadable parquet file: {error}", str(file), None, unreadable_fix(file)))
    if not scan.files:
        return problems
    problems += _schema_problems(list(zip(scan.files, scan.schemas)), expected)
    problems += _content_problems(scan, expected, layout, allow_flagged)
    has_keys = {"press_id", "position_id"} <= scan.columns
    if path.is_dir() and has_keys:
        problems += waveform_problems(path, scan.keys, manifest, scan.files)
    if manifest is not None:
        problems += manifest_problems(manifest, manifest_file, metadata, scan, pairs, layout)
    if path.is_dir():
        problems += integrity_problems(path, manifest, scan)
    return problems


def _readable_schemas(files: list[Path]) -> Iterator[pa.Schema]:
    """The schemas of the files that can be opened, in order (the first gives the dataset's metadata)."""
    for file in files:
        try:
            yield read_schema(file)
        except (OSError, pa.ArrowException):
            continue


# ---- pieces ----------------------------------------------------------------------------------------


def _expected_pairs(
    layout: Layout | None, manifest: dict | None, metadata: dict, schema: pa.Schema
) -> tuple[ElectrodePair, ...]:
    if layout is not None:
        return layout.pairs
    for source in (manifest or {}, metadata):
        if source.get("pairs"):
            try:
                return tuple(ElectrodePair(int(i), int(j)) for i, j in source["pairs"])
            except (TypeError, ValueError):
                pass
    found = [parse_pair_column(n) for n in schema.names]
    return tuple(p for kind, p in filter(None, found) if kind == "dR")


def _schema_problems(schemas: list[tuple[Path, pa.Schema]], expected: pa.Schema) -> list[Problem]:
    grouped: dict[tuple[str, str, str], list[Path]] = defaultdict(list)
    want = {f.name: f.type for f in expected}
    for file, schema in schemas:
        names = schema.names
        missing = [n for n in expected.names if n not in names]
        extra = [n for n in names if n not in want and n not in OPTIONAL_COLUMNS]  # source_run of a merge
        if missing:  # the text every reader refuses the file with (reader.refuse_missing_columns)
            problem = missing_columns_problem(missing, str(file))
            grouped[(str(problem.field), problem.message, str(problem.fix))].append(file)
        if extra:
            grouped[
                (
                    ", ".join(extra),
                    f"unexpected column(s): {', '.join(extra)}",
                    "drop these columns, or check that the manifest names the campaign's layout",
                )
            ].append(file)
        for field in schema:
            if field.name in want and not _equivalent_type(field.type, want[field.name]):
                grouped[
                    (
                        field.name,
                        f"column '{field.name}' has type {field.type}, expected {want[field.name]}",
                        f"cast the column to {want[field.name]}",
                    )
                ].append(file)
    return [Problem(message, where(files), column, fix) for (column, message, fix), files in grouped.items()]


def _equivalent_type(have: pa.DataType, want: pa.DataType) -> bool:
    """Types that hold the same values: what pandas writes back (large_string for string, a list of nulls
    for a flags column whose lists are all empty, timestamps in ns) is as good as the schema's own."""
    if have == want:
        return True
    if pa.types.is_string(want) or pa.types.is_large_string(want):
        return pa.types.is_string(have) or pa.types.is_large_string(have)
    if pa.types.is_list(want) and (pa.types.is_list(have) or pa.types.is_large_list(have)):
        item = have.value_type
        return pa.types.is_null(item) or _equivalent_type(item, want.value_type)
    if pa.types.is_timestamp(want) and pa.types.is_timestamp(have):
        return (have.tz is None) == (want.tz is None)
    return False


def _ids(series: pd.Series, limit: int = 8) -> str:
    values = sorted({int(v) for v in series if pd.notna(v)})
    text = ", ".join(str(v) for v in values[:limit])
    return text + (f", ... ({len(values)} in all)" if len(values) > limit else "")


def _files(scan: DatasetScan, indices: Any) -> str:
    return where([scan.files[int(i)] for i in sorted(set(indices))])


def _content_problems(
    scan: DatasetScan, expected: pa.Schema, layout: Layout | None, allow_flagged: bool
) -> list[Problem]:
    problems: list[Problem] = []
    rows = scan.keys
    has_ids = "press_id" in scan.columns
    for field in expected:
        bad = scan.nulls.get(field.name)
        if bad is None or not bad.count:
            continue
        ids = np.concatenate(bad.press_ids) if bad.press_ids else np.array([])
        which = f" (press ids {_ids(pd.Series(ids))})" if has_ids else ""
        problems.append(
            Problem(
                f"{bad.count} NaN/null value(s) in '{field.name}'{which}",
                _files(scan, bad.files),
                field.name,
                "re-press those presses (drop them and resume the campaign) or drop the rows",
            )
        )
    problems += value_problems(scan, has_ids, _ids, _files)
    if not has_ids:
        return problems
    # an exact copy of a row in the same file is a curation slip (a file concatenated to itself)
    copied = rows.duplicated(subset=["file", "press_id", "row_hash"], keep="first")
    if copied.any():
        problems.append(
            Problem(
                f"{int(copied.sum())} exact duplicate row(s) (press ids {_ids(rows.loc[copied, 'press_id'])})",
                _files(scan, rows.loc[copied, "file"]),
                "press_id",
                "keep one row per press: df.drop_duplicates() and write the file again",
            )
        )
    # a press both in a part and in presses.parquet is fine: duplicates count only with different rows
    distinct = rows.drop_duplicates(subset=["press_id", "row_hash"])
    dup = distinct["press_id"].duplicated(keep=False) & distinct["press_id"].notna()
    if dup.any():
        problems.append(
            Problem(
                f"duplicate press id(s) with different rows: {_ids(distinct.loc[dup, 'press_id'])}",
                _files(scan, distinct.loc[dup, "file"]),
                "press_id",
                "keep one row per press id (re-key with `neatskin dataset merge` if two campaigns were concatenated)",
            )
        )
    if layout is not None and {"x_mm", "y_mm"} <= scan.columns:
        x0, y0, x1, y1 = layout.bounds_mm
        tol = max(c.width_mm for c in layout.channels) / 2
        x, y = rows["x_mm"].to_numpy(float), rows["y_mm"].to_numpy(float)
        out = (x < x0 - tol) | (x > x1 + tol) | (y < y0 - tol) | (y > y1 + tol)
        if out.any():
            problems.append(
                Problem(
                    f"{int(out.sum())} press(es) outside the layout '{layout.name}' bounds x {x0:g}..{x1:g} mm, "
                    f"y {y0:g}..{y1:g} mm (+/- {tol:g} mm) (press ids {_ids(rows.loc[out, 'press_id'])})",
                    _files(scan, rows.loc[out, "file"]),
                    "x_mm, y_mm",
                    "check the calibration and the layout the manifest names; drop the rows if the presses missed the skin",
                )
            )
    if {"position_id", "x_mm", "y_mm"} <= scan.columns:
        grouped = rows.groupby("position_id")[["x_mm", "y_mm"]]
        spread = (grouped.max() - grouped.min()).max(axis=1)
        moved = spread[spread > 1e-9]
        if len(moved):
            problems.append(
                Problem(
                    f"position id(s) {_ids(pd.Series(moved.index))} have presses at different x/y",
                    _files(scan, range(len(scan.files))),
                    "position_id",
                    "give every distinct (x_mm, y_mm) its own position_id",
                )
            )
    flagged = rows["flagged"].to_numpy(bool)
    if "cut_pairs_only" in rows:  # a channel pinched shut is a measurement of the skin: noted, not refused
        flagged = flagged & ~rows["cut_pairs_only"].to_numpy(bool)
    if "flags" in scan.columns and not allow_flagged and flagged.any():
        counts = scan.flag_counts
        problems.append(
            Problem(
                f"{int(flagged.sum())} flagged press(es) ({', '.join(f'{k}: {v}' for k, v in counts.most_common())}; "
                f"press ids {_ids(rows.loc[flagged, 'press_id'])})",
                _files(scan, rows.loc[flagged, "file"]),
                "flags",
                "inspect them; drop them with `neatskin dataset export --drop-flagged`, or accept them with "
                "--allow-flagged",
            )
        )
    return problems

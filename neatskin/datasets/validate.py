"""Dataset validation: every problem in a campaign folder (schema, NaNs, duplicate press ids, positions
outside the layout, flagged presses, manifest consistency), one Problem each, naming file, column and fix.

The rows are read once, row group by row group (datasets/scan.py): memory holds one row group of full rows
plus a few key columns per press, so a merged dataset of 280,000 presses validates in bounded memory.
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

from neatskin.datasets.manifest import MANIFEST_NAME, read_manifest, resolve_manifest_path
from neatskin.datasets.paths import CONSOLIDATED_NAME, COPY_NAME, part_press_id, press_parts, waveform_parts
from neatskin.datasets.reader import press_files
from neatskin.datasets.scan import DatasetScan, read_schema, scan_files
from neatskin.datasets.schema import BASE_FIELDS, OPTIONAL_COLUMNS, decode_metadata, parse_pair_column, press_schema
from neatskin.datasets.values import metadata_layout, value_problems
from neatskin.datasets.writer import file_sha256, read_parquet
from neatskin.errors import ConfigError, DataError, Problem
from neatskin.layout import ElectrodePair, Layout, load_layout

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
        layout = _manifest_layout(path, manifest, manifest_file, problems)
    try:
        files = press_files(path)
    except DataError as exc:
        return problems + list(exc.problems)

    try:
        first_schema = next(_readable_schemas(files))
    except StopIteration:
        first_schema = None
    metadata = decode_metadata(first_schema.metadata) if first_schema is not None else {}
    if layout is None and manifest is None:
        layout = metadata_layout(path if path.is_dir() else path.parent, metadata, notes)
    pairs = _expected_pairs(layout, manifest, metadata, first_schema if first_schema is not None else pa.schema([]))
    expected = press_schema(pairs)
    nullable = {f.name: f.nullable for f in BASE_FIELDS}
    scan = scan_files(files, expected, nullable)
    for file, error in scan.unreadable:
        problems.append(Problem(f"unreadable parquet file: {error}", str(file), None, _unreadable_fix(file)))
    if not scan.files:
        return problems
    problems += _schema_problems(list(zip(scan.files, scan.schemas)), expected)
    problems += _content_problems(scan, expected, layout, allow_flagged)
    has_keys = {"press_id", "position_id"} <= scan.columns
    if path.is_dir() and has_keys:
        problems += _waveform_problems(path, scan.keys)
    if manifest is not None:
        problems += _manifest_problems(manifest, manifest_file, metadata, scan, pairs, layout)
    if path.is_dir():
        problems += _integrity_problems(path, manifest, scan)
    return problems


def _readable_schemas(files: list[Path]) -> Iterator[pa.Schema]:
    """The schemas of the files that can be opened, in order (the first gives the dataset's metadata)."""
    for file in files:
        try:
            yield read_schema(file)
        except (OSError, pa.ArrowException):
            continue


def _unreadable_fix(file: Path) -> str:
    if file.name == CONSOLIDATED_NAME:
        return (
            f"restore it from its copy: neatskin campaign finish {file.parent} (or cp {file.parent / COPY_NAME} "
            f"{file} when that copy's sha256 matches files_sha256 in manifest.json)"
        )
    return "move the file out of the folder; resume the campaign to press again"


def _same_rows(path: Path, copy: Path, recorded_sha256: str) -> bool:
    """Whether `path` holds the same rows as the campaign's intact copy: a file re-encoded without a change
    (e.g. a pandas round trip) is fine, a changed value or a flipped bit is not."""
    if not copy.is_file() or file_sha256(copy) != recorded_sha256:
        return False
    try:
        original = read_parquet(copy)
        return original.equals(read_parquet(path).cast(original.schema))
    except (OSError, pa.ArrowException, ValueError):
        return False


def _integrity_problems(folder: Path, manifest: dict | None, scan: DatasetScan) -> list[Problem]:
    """Recorded sha256 (presses.parquet, committed parts) and parts whose content is not what their name says."""
    problems = []
    manifest = manifest or {}
    files_raw = manifest.get("files_sha256")
    files: dict = files_raw if isinstance(files_raw, dict) else {}
    parts_sha_raw = manifest.get("parts_sha256")
    parts_sha: dict = parts_sha_raw if isinstance(parts_sha_raw, dict) else {}
    consolidated = folder / CONSOLIDATED_NAME
    if (
        CONSOLIDATED_NAME in files
        and consolidated.is_file()
        and file_sha256(consolidated) != files[CONSOLIDATED_NAME]
        and not _same_rows(consolidated, folder / COPY_NAME, files[CONSOLIDATED_NAME])
    ):
        problems.append(
            Problem(
                "presses.parquet differs from the file the campaign finished with (sha256 and rows): damaged or edited",
                str(consolidated),
                "files_sha256",
                _unreadable_fix(consolidated),
            )
        )
    for press_id, part in press_parts(folder).items():
        if str(press_id) in parts_sha and file_sha256(part) != parts_sha[str(press_id)]:
            problems.append(
                Problem(
                    "the part changed after it was committed (sha256 differs from the manifest's)",
                    str(part),
                    "parts_sha256",
                    "move the part out of presses/ and resume: the press is pressed again",
                )
            )
    ids_by_file = scan.keys.groupby("file", sort=False)["press_id"]
    for index, (file, schema) in enumerate(zip(scan.files, scan.schemas)):
        expected = part_press_id(file)
        if file.parent.name != "presses" or expected is None or "press_id" not in schema.names:
            continue
        ids = [int(i) for i in ids_by_file.get_group(index)] if index in ids_by_file.groups else []
        if not part_ids_valid(expected, ids):
            problems.append(
                Problem(
                    f"the part's name says press {expected} but it holds press id(s) {ids[:5]}",
                    str(file),
                    "press_id",
                    "move the part out of presses/ and resume: the press is pressed again",
                )
            )
    return problems


def part_ids_valid(first_press_id: int, ids: list) -> bool:
    """A part `part-{N:06d}.parquet` holds one or more rows: its press ids start with N and strictly increase
    (a part of one row holding press N is the common case)."""
    if not ids or ids[0] != first_press_id or any(i is None for i in ids):
        return False
    return all(a < b for a, b in zip(ids, ids[1:]))


# ---- pieces ----------------------------------------------------------------------------------------


def _manifest_layout(folder: Path, manifest: dict, manifest_file: str, problems: list[Problem]) -> Layout | None:
    layout_path = resolve_manifest_path(folder, manifest, "layout")
    if layout_path is None:
        return None
    try:
        return load_layout(layout_path)
    except ConfigError as exc:
        problems.append(
            Problem(
                f"the layout it names cannot be loaded: {exc.problems[0]}",
                manifest_file,
                "layout.path",
                "point layout.path at the campaign's skin layout TOML (relative to the campaign folder or absolute)",
            )
        )
        return None


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


def _where(files: list[Path]) -> str:
    return str(files[0]) if len(files) == 1 else f"{files[0]} (and {len(files) - 1} more files)"


def _schema_problems(schemas: list[tuple[Path, pa.Schema]], expected: pa.Schema) -> list[Problem]:
    grouped: dict[tuple[str, str, str], list[Path]] = defaultdict(list)
    want = {f.name: f.type for f in expected}
    for file, schema in schemas:
        names = schema.names
        missing = [n for n in expected.names if n not in names]
        extra = [n for n in names if n not in want and n not in OPTIONAL_COLUMNS]  # source_run of a merge
        if missing:
            grouped[
                (
                    ", ".join(missing),
                    f"missing column(s): {', '.join(missing)}",
                    "rewrite the file with every column of the layout's schema (or validate against the "
                    "layout the campaign used)",
                )
            ].append(file)
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
    return [Problem(message, _where(files), column, fix) for (column, message, fix), files in grouped.items()]


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
    return _where([scan.files[int(i)] for i in sorted(set(indices))])


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


def _waveform_problems(folder: Path, rows: pd.DataFrame) -> list[Problem]:
    """Waveform parts must belong to a press of the dataset and sit in that press's position partition."""
    known = rows[["press_id", "position_id"]].dropna()
    position_of = dict(zip(known["press_id"].astype(int), known["position_id"].astype(int)))
    orphans, misplaced = [], []
    for press_id, part in waveform_parts(folder).items():
        if press_id not in position_of:
            orphans.append(part)
        elif part.parent.name != f"position_id={position_of[press_id]}":
            misplaced.append(part)
    problems = []
    if orphans:
        problems.append(
            Problem(
                f"{len(orphans)} waveform part(s) of presses that are not in the dataset",
                _where(orphans),
                "press_id",
                "resume the campaign (it deletes orphans and presses them again) or delete the parts",
            )
        )
    if misplaced:
        problems.append(
            Problem(
                f"{len(misplaced)} waveform part(s) in another press's position_id partition",
                _where(misplaced),
                "position_id",
                "move each part to waveforms/position_id=<its press's position_id>/",
            )
        )
    return problems


def _manifest_problems(
    manifest: dict,
    manifest_file: str,
    metadata: dict,
    scan: DatasetScan,
    pairs: tuple[ElectrodePair, ...],
    layout: Layout | None,
) -> list[Problem]:
    problems: list[Problem] = []
    rows = scan.keys
    n = int(rows["press_id"].nunique()) if "press_id" in scan.columns else len(rows)
    counts_raw = manifest.get("counts")
    counts: dict = counts_raw if isinstance(counts_raw, dict) else {}
    if counts.get("completed") is not None and counts["completed"] != n:
        problems.append(
            Problem(
                f"counts.completed is {counts['completed']} but the data holds {n} presses",
                manifest_file,
                "counts.completed",
                "resume the campaign (it rewrites the counts) or correct counts.completed",
            )
        )
    if manifest.get("status") == "complete" and counts.get("planned") is not None and counts["planned"] != n:
        problems.append(
            Problem(
                f"status is complete but {n} of {counts['planned']} planned presses are present",
                manifest_file,
                "counts.planned",
                "resume the campaign to press the missing ones, or set status to interrupted",
            )
        )
    if "seed" in manifest and "seed" in metadata and manifest["seed"] != metadata["seed"]:
        problems.append(
            Problem(
                f"seed {manifest['seed']!r} differs from the parquet metadata's {metadata['seed']!r}",
                manifest_file,
                "seed",
                "these files come from different runs; restore the campaign's own manifest",
            )
        )
    listed = manifest.get("pairs")
    if listed and layout is not None:
        try:
            as_pairs = tuple(ElectrodePair(int(i), int(j)) for i, j in listed)
        except (TypeError, ValueError):
            as_pairs = None
        if as_pairs != layout.pairs:
            problems.append(
                Problem(
                    "pairs do not match the layout's electrode pairs",
                    manifest_file,
                    "pairs",
                    "rewrite pairs from the layout, or name the layout the campaign used",
                )
            )
    if "layout" in manifest and "layout" in metadata and not same_file_ref(manifest["layout"], metadata["layout"]):
        problems.append(
            Problem(
                f"layout {manifest['layout']!r} differs from the parquet metadata's {metadata['layout']!r}",
                manifest_file,
                "layout",
                "name the layout the presses were recorded on",
            )
        )
    if manifest.get("campaign") and "campaign" in scan.columns:
        other = sorted(scan.campaigns - {manifest["campaign"]})
        if other:
            problems.append(
                Problem(
                    f"rows belong to campaign(s) {other}, the manifest says {manifest['campaign']!r}",
                    manifest_file,
                    "campaign",
                    "merge campaigns with `neatskin dataset merge`",
                )
            )
    return problems


def same_file_ref(a: Any, b: Any) -> bool:
    """Two references to an input file (a path string or a dict with sha256/name/path) name the same file:
    compared by the first of sha256, name, path that both give."""
    a = a if isinstance(a, dict) else {"path": a}
    b = b if isinstance(b, dict) else {"path": b}
    for key in ("sha256", "name", "path"):
        if a.get(key) is not None and b.get(key) is not None:
            return a[key] == b[key]
    return True

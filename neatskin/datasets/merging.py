"""Merging campaigns into one dataset: press ids re-keyed, position ids made physical, each row's source run
named in a `source_run` column, provenance kept, the rows streamed source by source so that memory stays bounded however many presses the merge holds.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from neatskin.datasets import curation
from neatskin.datasets.consolidate import FINALIZE_BATCH
from neatskin.datasets.durable import write_durably
from neatskin.datasets.manifest import create_manifest, utc_now_iso
from neatskin.datasets.manifestchecks import same_file_ref
from neatskin.datasets.paths import CONSOLIDATED_NAME
from neatskin.datasets.reader import press_files, read_press_table
from neatskin.datasets.rigkind import merged_rig, refuse_mixed_rigs, source_rigs
from neatskin.datasets.schema import decode_metadata, encode_metadata
from neatskin.datasets.tables import refuse_missing_columns, unreadable_presses
from neatskin.datasets.writer import deduplicate_sorted, read_parquet
from neatskin.errors import DataError

POSITION_TOLERANCE_MM = 0.01  # two presses this close (same layout and calibration) are one physical position


def _ref_key(ref: Any) -> str | None:
    """What identifies an input file across campaigns: its sha256, else its name, else its path."""
    if isinstance(ref, dict):
        for key in ("sha256", "name", "path"):
            if ref.get(key) is not None:
                return f"{key}:{ref[key]}"
        return None
    return None if ref is None else f"path:{ref}"


def _check_sources(sources: list[Path], allow_incomplete: bool) -> list[str]:
    """Refuse a folder named twice, and (unless allow_incomplete) a campaign that runs or is incomplete;
    returns each source's status."""
    seen: dict[Path, Path] = {}
    for folder in sources:
        key = folder.resolve()
        if key in seen:
            raise DataError(
                f"the same dataset is named twice ({seen[key]} and {folder})",
                file=str(folder),
                field="folders",
                fix="name each campaign once; merging a campaign with itself duplicates every press",
            )
        seen[key] = folder
    statuses = []
    for folder in sources:
        if folder.is_file():
            statuses.append("file")
            continue
        manifest = curation.manifest_or_empty(folder)
        status = curation.campaign_status(folder, manifest) if manifest else "no manifest (a plain dataset folder)"
        statuses.append(status)
        if manifest and status != "complete" and not allow_incomplete:
            raise DataError(
                f"the campaign is not complete (status: {status})",
                file=str(folder),
                field="status",
                fix="finish it first (neatskin campaign resume), or merge what it holds with --allow-incomplete "
                "(recorded in the merged manifest)",
            )
    return statuses


def _schema_types(schema: pa.Schema) -> pa.Schema:
    """The merged schema: the first source's columns with the press schema's own types for the fixed columns (a
    source written back by pandas may type an all-empty `flags` as list<null>, which no other source casts to)."""
    from neatskin.datasets.schema import BASE_FIELDS

    canonical = {f.name: f for f in BASE_FIELDS}
    return pa.schema([canonical.get(f.name, f) for f in schema])


def _refuse_invalid(sources: list[Path], allow_invalid: bool) -> dict[str, list[str]]:
    """Refuse a source `dataset validate` refuses (flagged presses aside: a merge keeps and counts them), unless
    allow_invalid; returns each accepted invalid source's problems, recorded in the merged manifest."""
    from neatskin.datasets.validate import validate_dataset

    invalid: dict[str, list[str]] = {}
    for folder in sources:
        problems = [p for p in validate_dataset(folder, allow_flagged=True) if p.field not in _INCOMPLETE_FIELDS]
        if problems and not allow_invalid:
            shown = "; ".join(f"[{p.field}] {p.message}" if p.field else p.message for p in problems[:3])
            more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
            raise DataError(
                f"`dataset validate` refuses it: {shown}{more}",
                file=str(folder),
                field=problems[0].field,
                fix=f"repair it (neatskin dataset validate {folder} lists every problem), or merge it anyway with "
                "--allow-invalid (recorded in the merged manifest)",
            )
        if problems:
            invalid[str(folder.resolve())] = [str(p) for p in problems]
    return invalid


# what an incomplete campaign's manifest says of itself; --allow-incomplete (checked before) rules on these
_INCOMPLETE_FIELDS = ("status", "counts.completed", "counts.planned")


def _physical_position_ids(
    positions: list[pd.DataFrame], calibration_keys: list[tuple[str | None, str | None]], tolerance_mm: float
) -> list[dict[int, int]]:
    """Per source, {source position id: merged position id}, from each source's per-position (x_mm, y_mm)
    (indexed by position id, sorted). Positions of sources on the same layout and calibration that lie within
    tolerance_mm of each other share one id; ids are numbered in order of first appearance (source order,
    then the source's position ids)."""
    centers: dict[tuple[str | None, str | None], list[tuple[float, float, int]]] = {}
    next_id = 0
    maps = []
    for per_position, key in zip(positions, calibration_keys):
        known = centers.setdefault(key, [])
        mapping = {}
        for pos, (x, y) in zip(per_position.index, per_position.to_numpy()):
            match = None
            if known:
                xy = np.array([(cx, cy) for cx, cy, _ in known])
                dist = np.hypot(xy[:, 0] - x, xy[:, 1] - y)
                k = int(np.argmin(dist))
                if dist[k] <= tolerance_mm:
                    match = known[k][2]
            if match is None:
                match = next_id
                next_id += 1
                known.append((float(x), float(y), match))
            mapping[int(pos)] = match
        maps.append(mapping)
    return maps


MERGE_ROW_GROUP = FINALIZE_BATCH  # rows per row group of a merged presses.parquet, as a campaign's own


@dataclass(frozen=True)
class _SourcePlan:
    """What merge needs to know of a source before it streams the rows: a summary, not the rows."""

    schema: pa.Schema
    metadata: dict[str, Any]
    manifest: dict[str, Any]
    positions: pd.DataFrame  # x_mm, y_mm of each position's first press, indexed by position id (sorted)
    presses: int
    flagged: int
    max_press_id: int | None


_PLAN_COLUMNS = ("press_id", "position_id", "x_mm", "y_mm", "flags")  # what a merge plans from


def _plan_source(folder: Path) -> _SourcePlan:
    """A source's summary from five small columns of its presses (consolidated file and parts, first copy
    of a press id kept)."""
    files = press_files(folder)
    try:
        refuse_missing_columns(pq.read_schema(files[0]), files[0])  # the damaged source named, not the healthy one
    except (OSError, pa.ArrowException) as exc:
        raise unreadable_presses(exc, files[0]) from exc
    tables = []
    for path in files:
        try:
            table = read_parquet(path, columns=list(_PLAN_COLUMNS))
            if table.num_columns < len(_PLAN_COLUMNS):  # pyarrow leaves out a column the file lacks
                refuse_missing_columns(pq.read_schema(path), path)
        except (OSError, pa.ArrowException) as exc:
            raise unreadable_presses(exc, path) from exc
        tables.append(table)
    keys = deduplicate_sorted(pa.concat_tables(tables, promote_options="permissive"))
    frame = keys.select(["position_id", "x_mm", "y_mm"]).to_pandas()
    schema = pq.read_schema(files[0])
    return _SourcePlan(
        schema=schema,
        metadata=decode_metadata(schema.metadata),
        manifest=curation.manifest_or_empty(folder),
        positions=frame.groupby("position_id", sort=True)[["x_mm", "y_mm"]].first(),
        presses=keys.num_rows,
        flagged=int(curation.flagged_mask(keys).sum()),
        max_press_id=int(pc.max(keys.column("press_id")).as_py()) if keys.num_rows else None,
    )


SOURCE_RUN = "source_run"  # the merged dataset's column naming the run each row came from


def source_run_names(sources: Sequence[Path]) -> list[str]:
    """Each source's run name: its folder's name (a file's stem), never a path; a name two sources share gets
    `#2`, `#3`... in source order, so every row names exactly one source."""
    names = [(folder.stem if folder.is_file() else folder.resolve().name) or "run" for folder in sources]
    seen: dict[str, int] = {}
    out = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 and names.count(name) == 1 else f"{name}#{seen[name]}")
    return out


def _with_source_run(table: pa.Table, run: str) -> pa.Table:
    """The rows with `source_run` after `campaign`: kept as is when the source is itself a merge (its rows
    already name their runs), else the source's run name on every row."""
    if SOURCE_RUN in table.column_names:
        return table
    column = pa.array([run] * table.num_rows, pa.string())
    return table.add_column(table.schema.get_field_index("campaign") + 1, pa.field(SOURCE_RUN, pa.string()), column)


def _rekeyed(table: pa.Table, press_offset: int, mapping: dict[int, int], schema: pa.Schema) -> pa.Table:
    """A source's rows with press ids shifted by press_offset and position ids mapped to physical ids."""
    pos = table.column("position_id").to_numpy()
    keys = np.array(sorted(mapping), dtype=np.int64)
    new_pos = np.array([mapping[k] for k in keys], dtype=np.int32)[np.searchsorted(keys, pos)]
    index = table.schema.get_field_index
    table = table.set_column(
        index("press_id"),
        table.schema.field("press_id"),
        pc.add(table.column("press_id"), pa.scalar(press_offset, pa.int64())),
    )
    table = table.set_column(index("position_id"), table.schema.field("position_id"), pa.array(new_pos, pa.int32()))
    table = table.replace_schema_metadata(None)
    return table if table.schema.equals(schema) else table.cast(schema)


def _as_planned(folder: Path, plan: _SourcePlan) -> pa.Table:
    """A source's rows as its plan saw them: a campaign still running (--allow-incomplete) may have added
    presses since, which are left out (their ids would overlap the next source's); anything else that
    changed is an error."""
    table = read_press_table(folder)
    if plan.max_press_id is None:
        table = table.slice(0, 0)
    elif table.num_rows and pc.max(table.column("press_id")).as_py() > plan.max_press_id:
        table = table.filter(pc.less_equal(table.column("press_id"), pa.scalar(plan.max_press_id, pa.int64())))
    if table.num_rows != plan.presses:
        raise DataError(
            f"the dataset changed while it was merged ({plan.presses} presses, then {table.num_rows})",
            file=str(folder),
            fix="merge again once nothing writes to it",
        )
    return table


def merge(
    folders: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    allow_mixed: bool = False,
    allow_incomplete: bool = False,
    allow_invalid: bool = False,
    allow_mixed_rigs: bool = False,
    tolerance_mm: float = POSITION_TOLERANCE_MM,
) -> Path:
    """Merge campaigns into one dataset folder. Press ids are re-keyed (source k's ids shifted by the sum of
    (max id + 1) of the sources before it); position ids are physical: presses of campaigns on the same layout
    and calibration within tolerance_mm share an id, so a grouped split never puts one spot on both sides.
    Refuses different pair sets always, different layouts or wirings unless allow_mixed, different rigs (a simulated
    or a real printer, a simulated or a real DAQ: a dry run beside a real-printer run) unless allow_mixed_rigs, a
    folder named twice, and campaigns that run or are incomplete unless allow_incomplete (recorded in the manifest).
    The merged manifest's `source_rigs` names each source's rig and presses; its `rig` is their one rig, or
    {"kind": "mixed"} when allowed to differ.

    Memory stays bounded as the merged dataset grows: merge plans from four small columns of each source,
    then streams the sources one at a time into presses.parquet (at most the largest source plus one row
    group of MERGE_ROW_GROUP rows in memory)."""
    sources = [Path(f) for f in folders]
    out = Path(out)
    if len(sources) < 2:
        raise DataError("merge needs at least two campaign folders", field="folders", fix="name two or more")
    curation.empty_output(out)
    statuses = _check_sources(sources, allow_incomplete)
    plans = [_plan_source(folder) for folder in sources]
    first_folder, first = sources[0], plans[0]
    for folder, plan in zip(sources[1:], plans[1:]):
        if [n for n in plan.schema.names if n != SOURCE_RUN] != [n for n in first.schema.names if n != SOURCE_RUN]:
            raise DataError(
                f"its electrode pairs differ from those of {first_folder}",
                file=str(folder),
                field="pairs",
                fix="only campaigns measuring the same pairs can share one table",
            )
        for key in ("layout", "wiring"):
            a = first.manifest.get(key, first.metadata.get(key))
            b = plan.manifest.get(key, plan.metadata.get(key))
            if not allow_mixed and a is not None and b is not None and not same_file_ref(a, b):
                raise DataError(
                    f"{key} {b!r} differs from {a!r} of {first_folder}",
                    file=str(folder),
                    field=key,
                    fix="merge only campaigns on one skin and wiring, or pass --allow-mixed",
                )
    runs = source_run_names(sources)
    rigs = [
        entry
        for folder, plan, run in zip(sources, plans, runs)
        for entry in source_rigs(run, str(folder.resolve()), plan.presses, plan.manifest, plan.metadata)
    ]
    refuse_mixed_rigs(rigs, allow_mixed_rigs)
    invalid = _refuse_invalid(sources, allow_invalid)  # after the checks that name a merge's own fields
    calibration = [
        (
            _ref_key(p.manifest.get("layout", p.metadata.get("layout"))),
            _ref_key(p.manifest.get("printer", p.metadata.get("printer"))),
        )
        for p in plans
    ]
    position_maps = _physical_position_ids([p.positions for p in plans], calibration, tolerance_mm)
    provenance, offsets = [], []
    press_offset = 0
    for folder, plan, mapping, status in zip(sources, plans, position_maps, statuses):
        offsets.append(press_offset)
        provenance.append(
            {
                "folder": str(folder.resolve()),
                "status": status,
                "presses": plan.presses,
                "press_id_offset": press_offset,
                "position_ids": {str(k): v for k, v in sorted(mapping.items())},
                "metadata": {k: v for k, v in plan.metadata.items() if k != "pairs"},
                "manifest": plan.manifest,
            }
        )
        if plan.max_press_id is not None:
            press_offset += plan.max_press_id + 1
    out.mkdir(parents=True, exist_ok=True)
    refs = curation.copy_inputs(out, sources, [p.manifest for p in plans])
    rig, rig_metadata = merged_rig(rigs)
    metadata = {
        "pairs": first.metadata.get("pairs"),
        "software_version": first.metadata.get("software_version"),
        "merged_from": provenance,
        **rig_metadata,
        **refs,
    }
    manifest = {
        "kind": "merge",
        "allow_mixed": allow_mixed,
        "allow_incomplete": allow_incomplete,
        "allow_invalid": allow_invalid,
        "allow_mixed_rigs": allow_mixed_rigs,
        **({"rig": rig} if rig is not None else {}),
        "source_rigs": rigs,
        "invalid_sources": invalid,
        "position_tolerance_mm": tolerance_mm,
        "sources": [p["folder"] for p in provenance],
        **refs,
    }
    seeds = {json.dumps(p.manifest.get("seed", p.metadata.get("seed"))) for p in plans}
    if len(seeds) == 1:
        metadata["seed"] = manifest["seed"] = json.loads(seeds.pop())
    plain = _with_source_run(_schema_types(first.schema.remove_metadata()).empty_table(), "").schema.remove_metadata()
    metadata["source_runs"] = runs

    def tables() -> Iterator[pa.Table]:
        for folder, plan, mapping, offset, run in zip(sources, plans, position_maps, offsets, runs):
            try:
                yield _rekeyed(_with_source_run(_as_planned(folder, plan), run), offset, mapping, plain)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as exc:
                raise DataError(
                    f"its columns do not convert to the press schema: {exc}",
                    file=str(folder),
                    fix=f"check it with neatskin dataset validate {folder}; rewrite the columns it names",
                ) from exc

    _stream_table(out / CONSOLIDATED_NAME, plain.with_metadata(encode_metadata(metadata)), tables())
    n_rows = sum(p.presses for p in plans)
    counts = {"planned": n_rows, "completed": n_rows, "flagged": sum(p.flagged for p in plans)}
    create_manifest(out, **{"status": "complete", "finished_at": utc_now_iso(), "counts": counts, **manifest})
    return out


def _stream_table(path: Path, schema: pa.Schema, tables: Iterator[pa.Table]) -> Path:
    """Write tables of one schema as one parquet file, atomically and durably, in row groups of
    MERGE_ROW_GROUP rows, holding at most one row group plus one incoming table."""

    def write(handle: IO[bytes]) -> None:
        with pq.ParquetWriter(handle, schema, write_page_checksum=True) as writer:
            pending: list[pa.Table] = []
            rows = 0
            for table in tables:
                pending.append(table)
                rows += table.num_rows
                if rows >= MERGE_ROW_GROUP:
                    whole = pa.concat_tables(pending).combine_chunks()
                    full = rows - rows % MERGE_ROW_GROUP
                    writer.write_table(whole.slice(0, full), row_group_size=MERGE_ROW_GROUP)
                    pending, rows = [whole.slice(full)], rows - full
            if rows or not pending:
                writer.write_table(
                    pa.concat_tables(pending) if pending else schema.empty_table(), row_group_size=MERGE_ROW_GROUP
                )

    path.parent.mkdir(parents=True, exist_ok=True)
    return write_durably(path, write)

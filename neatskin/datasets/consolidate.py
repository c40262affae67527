"""Finishing a campaign folder: its committed parts consolidated into presses.parquet (and its copy), crash-safe.

`consolidate` is what `CampaignWriter.finalize` does once its batch is written: every durable press,
sorted by press_id, in row groups of FINALIZE_BATCH rows with the writer's metadata; the file is
replaced atomically, then copied (presses.copy.parquet), and only then are the parts deleted, so a
kill at any point leaves a folder the next writer resumes and finalizes again. Readers deduplicate
a press found both in the consolidated file and in a part.
"""

from __future__ import annotations

import filecmp
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import IO

import pyarrow as pa
import pyarrow.parquet as pq

from neatskin.datasets.durable import write_durably
from neatskin.datasets.paths import CONSOLIDATED_NAME, COPY_NAME, press_parts
from neatskin.datasets.tables import deduplicate_sorted, read_tables, write_table_durably

FINALIZE_BATCH = 4096  # rows per row group of presses.parquet: finalize's memory stays flat as campaigns grow
READ_BATCH = 128  # at most this many parts read back at a time (one-row parts: a one-row table costs more than its row)


def consolidate(
    folder: Path, schema: pa.Schema, part_last: Mapping[int, int], *, fsync: bool, dir_fd: int | None
) -> Path:
    """Consolidate every durable press of `folder` into presses.parquet (sorted by press_id, `schema`'s
    metadata, row groups of FINALIZE_BATCH rows), copy it, then delete the parts. `part_last` maps each
    part's first press id to its last (the writer's record of what it committed or verified); `dir_fd`
    is the parts folder, fsync'd after the deletions when `fsync`. Idempotent."""
    consolidated = folder / CONSOLIDATED_NAME
    parts = press_parts(folder)
    if not parts and consolidated.exists():
        keep_copy(folder, consolidated, fsync=fsync)
        return consolidated
    plain = schema.remove_metadata()
    if consolidated.exists() or not parts_in_order(parts, part_last):
        # a finalize was killed half-way (or parts interleave): the rare path, rows held in memory once
        tables = [read_tables([consolidated], plain)] if consolidated.exists() else []
        table = pa.concat_tables([*tables, read_tables(list(parts.values()), plain)])
        table = deduplicate_sorted(table).replace_schema_metadata(schema.metadata)
        write_table_durably(consolidated, table, fsync=fsync)
    else:  # the parts hold distinct ids, in order by name: stream them, FINALIZE_BATCH rows per row group
        reads = read_groups(parts, part_last)

        def stream(handle: IO[bytes]) -> None:
            with pq.ParquetWriter(handle, schema, write_page_checksum=True) as out:
                pending: list[pa.Table] = []
                rows = 0
                for k, paths in enumerate(reads):
                    chunk = read_tables(paths, plain).combine_chunks()
                    pending.append(chunk)
                    rows += chunk.num_rows
                    last = k == len(reads) - 1
                    while rows >= FINALIZE_BATCH or (last and rows):
                        table = pa.concat_tables(pending).combine_chunks()
                        group = min(rows, FINALIZE_BATCH)
                        out.write_table(table.slice(0, group), row_group_size=FINALIZE_BATCH)
                        pending, rows = [table.slice(group)], rows - group

        write_durably(consolidated, stream, fsync=fsync)
    keep_copy(folder, consolidated, fsync=fsync)  # before the parts go: a damaged presses.parquet stays recoverable
    for path in parts.values():
        path.unlink(missing_ok=True)
    if fsync and dir_fd is not None:
        os.fsync(dir_fd)
    return consolidated


def read_groups(parts: Mapping[int, Path], part_last: Mapping[int, int]) -> list[list[Path]]:
    """The parts (in order) in groups read back together: up to READ_BATCH parts, closed as soon as they
    may hold FINALIZE_BATCH rows, so finalize holds about one row group whatever the parts' size."""
    groups: list[list[Path]] = []
    current: list[Path] = []
    rows = 0
    for first, path in parts.items():
        current.append(path)
        rows += part_last[first] - first + 1  # at most: ids strictly increase from the name's
        if len(current) >= READ_BATCH or rows >= FINALIZE_BATCH:
            groups.append(current)
            current, rows = [], 0
    return [*groups, current] if current else groups


def parts_in_order(parts: Mapping[int, Path], part_last: Mapping[int, int]) -> bool:
    """True when every part's ids are known and each part starts after the one before it ends."""
    previous_last = -1
    for first in parts:
        last = part_last.get(first)
        if last is None or first <= previous_last:
            return False
        previous_last = last
    return True


def keep_copy(folder: Path, consolidated: Path, *, fsync: bool) -> None:
    """presses.copy.parquet, byte for byte (left alone when it already is)."""
    copy = folder / COPY_NAME
    if copy.exists() and filecmp.cmp(consolidated, copy, shallow=False):
        return

    def stream(handle: IO[bytes]) -> None:  # block by block: a large campaign's file is never held whole
        with open(consolidated, "rb") as source:
            shutil.copyfileobj(source, handle, 1 << 20)

    write_durably(copy, stream, fsync=fsync)

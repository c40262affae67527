"""The crash-safe campaign writer: durable parquet parts of presses, raw waveforms beside them, resume and finalize.

Durability: by default (the real rig) every press is one part and `write_press` returns only when it is
complete on disk (temp file, fsync, atomic rename, fsync of the folder). With a batch (a dry run, whose
presses are recomputed identically from (seed, press_id)), presses wait in memory until `batch_presses` of
them or `batch_s` seconds have gathered, or until `flush()`, and are then written as one part. A part is
named after the press id of its first row and holds one or more rows whose press ids strictly increase;
one-row parts are the per-press parts. The part is the commit record: waveforms are written first,
so a kill between the two leaves an orphan waveform part that the next writer deletes (the press is
not in `completed_press_ids()` and will be pressed again). A kill inside a write leaves only a hidden
temp file, which readers ignore and the next writer removes; a kill with presses in the batch loses them.
`finalize` consolidates the parts into presses.parquet (`consolidate`, crash-safe and idempotent).

Waveforms are stored one row per sample: columns press_id (int64), sample (int32) and one column per
named signal, in `waveforms/position_id=K/part-{press_id:06d}.parquet` (hive partitioning, so pyarrow,
DuckDB and Spark add position_id as a column).
"""

from __future__ import annotations

import hashlib
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import neatskin
from neatskin.datasets.consolidate import consolidate
from neatskin.datasets.durable import fsync_dir, remove_temp_files, write_bytes_durably, write_durably
from neatskin.datasets.paths import (
    CONSOLIDATED_NAME,
    PRESSES_DIR,
    WAVEFORMS_DIR,
    part_name,
    press_parts,
    waveform_parts,
)
from neatskin.datasets.schema import CheckedRow, RowEncoder, decode_metadata, encode_metadata, press_schema
from neatskin.datasets.tables import (  # re-exported: callers import them from here
    deduplicate_sorted,
    file_sha256,
    read_parquet,
    read_tables,
    waveform_table,
    write_table_durably,
)
from neatskin.datasets.waveformcheck import refuse_lost_waveforms
from neatskin.errors import DataError
from neatskin.layout import ElectrodePair

__all__ = [
    "CampaignWriter",
    "deduplicate_sorted",
    "dry_run_batch_presses",
    "file_sha256",
    "read_parquet",
    "read_tables",
    "waveform_table",
    "write_table_durably",
]

MAX_BATCH_PRESSES = 256  # presses per part of a batched dry run: a kill loses at most these, recomputed on resume
DRY_RUN_BATCH_S = 1.0  # a batch waits at most this long, so the live monitor sees presses land every second
BATCH_FROM_PRESSES = 512  # shorter dry runs take seconds: they keep one part per press, as the real rig writes
log = logging.getLogger(__name__)


def dry_run_batch_presses(planned: int) -> int:
    """Presses per part for a dry run of `planned` presses: MAX_BATCH_PRESSES (each part also closes after
    DRY_RUN_BATCH_S), or 1 for a campaign under BATCH_FROM_PRESSES presses (the smoke protocol, short tests),
    whose parts are then exactly the real rig's."""
    return MAX_BATCH_PRESSES if int(planned) >= BATCH_FROM_PRESSES else 1


class CampaignWriter:
    """Writes a campaign folder press by press; reopen the same folder to resume.

    `metadata` (JSON-serialisable values) goes into every file's key-value metadata under `neatskin.`;
    `software_version` defaults to neatskin.__version__. `fsync=False` is for tests and throwaway runs only.
    `batch_presses` > 1 (with `batch_s`) gathers presses into one part, for runs whose presses can be
    recomputed (the dry run): call `flush()` (or `close()`) to make the gathered presses durable.
    """

    def __init__(
        self,
        folder: str | os.PathLike,
        pairs: Sequence[ElectrodePair],
        metadata: Mapping[str, Any],
        *,
        fsync: bool = True,
        known_sha256: Mapping[int, str] | None = None,
        batch_presses: int = 1,
        batch_s: float = DRY_RUN_BATCH_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if int(batch_presses) < 1 or not batch_s > 0:
            raise DataError(
                f"batch_presses = {batch_presses} and batch_s = {batch_s} must be >= 1 and > 0",
                field="batch_presses",
                fix="use batch_presses=1 for one durable part per press",
            )
        self.folder = Path(folder)
        self.fsync = fsync
        self.batch_presses, self.batch_s, self._clock = int(batch_presses), float(batch_s), clock
        self._batch: list[CheckedRow] = []
        self._batch_ids: set[int] = set()
        self._batch_started = 0.0
        self._part_last: dict[int, int] = {}  # first press id of a part -> its last press id
        self.part_sha256: dict[int, str] = {int(k): v for k, v in (known_sha256 or {}).items()}
        meta = {"software_version": neatskin.__version__, **dict(metadata)}
        self.schema = press_schema(pairs, meta)
        self.metadata = decode_metadata(self.schema.metadata)
        self.pairs = tuple(ElectrodePair(i, j) for i, j in self.metadata["pairs"])
        self._encoder = RowEncoder(self.schema)
        self._parts_dir = self.folder / PRESSES_DIR
        self._waveforms_dir = self.folder / WAVEFORMS_DIR
        new_folder = not self.folder.exists()
        self._parts_dir.mkdir(parents=True, exist_ok=True)
        if new_folder and fsync:
            fsync_dir(self.folder.parent)
        self._recover()
        self._dir_fd: int | None = os.open(self._parts_dir, os.O_RDONLY)
        self._position_dirs: set[Path] = set()

    # ---- resume ------------------------------------------------------------------------------

    def _recover(self) -> None:
        """Remove what a killed writer left half-done and load the ids of the durable presses."""
        for folder in (self.folder, self._parts_dir):
            remove_temp_files(folder)
        if self._waveforms_dir.is_dir():
            for sub in self._waveforms_dir.iterdir():
                remove_temp_files(sub)
        parts = press_parts(self.folder)
        self._completed: set[int] = set()
        for press_id, path in parts.items():
            ids = self._verified_part(press_id, path).column("press_id").to_pylist()
            twice = self._completed.intersection(ids)
            if twice:
                raise DataError(
                    f"press id(s) {sorted(twice)[:5]} are in this part and in another part",
                    file=str(path),
                    field="press_id",
                    fix=f"move {path.name} out of {path.parent} (its presses are pressed again on resume), "
                    "or restore the campaign's own files",
                )
            self._completed.update(ids)
            self._part_last[press_id] = ids[-1]
        consolidated = self.folder / CONSOLIDATED_NAME
        existing = [consolidated] if consolidated.exists() else []
        existing += list(parts.values())[:1]
        for path in existing:
            self._check_compatible(path)
        if consolidated.exists():
            ids = read_parquet(consolidated, columns=["press_id"]).column("press_id").to_pylist()
            self._completed.update(int(i) for i in ids)
        for press_id, path in waveform_parts(self.folder).items():
            if press_id not in self._completed:
                path.unlink(missing_ok=True)  # orphan: its press was never committed
        refuse_lost_waveforms(self.folder, self._completed, parts, self._part_last)

    def _verified_part(self, press_id: int, path: Path) -> pa.Table:
        """A committed part's rows, refused unless it is intact (recorded sha256, page checksums), holds press
        ids that start with the one its name says and strictly increase, and belongs to this campaign (name
        and seed)."""
        fix = (
            f"move {path.name} out of {path.parent} (its press is pressed again on resume), "
            "or restore the campaign's own file"
        )
        recorded = self.part_sha256.get(press_id)
        if recorded is not None and file_sha256(path) != recorded:
            raise DataError(
                f"the part changed after it was committed (sha256 differs from the manifest's {recorded[:12]})",
                file=str(path),
                fix=fix,
            )
        try:
            handle = pq.ParquetFile(path, page_checksum_verification=True)
            meta = decode_metadata(handle.schema_arrow.metadata)
            table = handle.read(use_threads=False)
        except (OSError, pa.ArrowException) as exc:
            raise DataError(f"cannot read a committed part: {exc}", file=str(path), fix=fix) from exc
        ids = table.column("press_id").to_pylist() if "press_id" in table.column_names else []
        if not ids or ids[0] != press_id:
            raise DataError(
                f"the part's name says press {press_id} but it holds press id(s) {ids[:5]}",
                file=str(path),
                field="press_id",
                fix=fix,
            )
        steps = np.diff(np.asarray(ids, dtype=np.int64))
        if (steps <= 0).any():
            k = int(np.argmax(steps <= 0))
            raise DataError(
                f"the part's press ids do not strictly increase (press {ids[k]} then {ids[k + 1]})",
                file=str(path),
                field="press_id",
                fix=fix,
            )
        own = self.metadata.get("campaign")
        found = table.column("campaign").to_pylist() if "campaign" in table.column_names else [None]
        foreign = next((c for c in found if c != own), None) if own is not None else None
        if own is not None and (foreign is not None or not found or meta.get("seed") != self.metadata.get("seed")):
            shown = foreign if foreign is not None else (found[0] if found else None)
            raise DataError(
                f"the part belongs to another campaign ({shown!r}, seed {meta.get('seed')!r}), "
                f"not {own!r} (seed {self.metadata.get('seed')!r})",
                file=str(path),
                field="campaign",
                fix=fix,
            )
        self._check_compatible(path)
        return table

    def _check_compatible(self, path: Path) -> None:
        try:
            found = pq.read_schema(path)
        except (OSError, pa.ArrowException) as exc:
            raise DataError(
                f"cannot read an existing part: {exc}",
                file=str(path),
                fix="move the damaged file out of the campaign folder, then resume",
            ) from exc
        if found.names != self.schema.names:
            missing = sorted(set(self.schema.names) - set(found.names))
            extra = sorted(set(found.names) - set(self.schema.names))
            raise DataError(
                f"existing data has other columns (missing {missing[:3]}, extra {extra[:3]})",
                file=str(path),
                field="pairs",
                fix="resume with the layout the campaign started with, or write to a new folder",
            )

    def completed_press_ids(self) -> set[int]:
        """Ids of the presses that are durable (in a part or in the consolidated file); a press still in the
        batch is not."""
        return set(self._completed)

    def batched_press_ids(self) -> set[int]:
        """Ids of the presses written but still in the batch, durable at the next flush."""
        return set(self._batch_ids)

    # ---- writing -----------------------------------------------------------------------------

    def write_press(self, row: Mapping[str, Any], waveforms: Mapping[str, np.ndarray] | None = None) -> Path:
        """Add one press; with batch_presses=1 it is durable when this returns, else once its batch is written.
        Returns the path of the part that holds (or will hold) it. Refuses a press id already written."""
        checked = self._encoder.check(row)
        press_id = checked.press_id
        if press_id < 0:
            raise DataError(f"press_id must be >= 0, got {press_id}", field="press_id", fix="number presses from 0")
        if press_id in self._completed or press_id in self._batch_ids:
            where = "durable" if press_id in self._completed else "written (in the batch not yet on disk)"
            raise DataError(
                f"press {press_id} is already {where} in {self.folder}",
                field="press_id",
                fix="skip the ids in completed_press_ids() when resuming",
            )
        if self._batch and press_id <= self._batch[-1].press_id:
            self.flush()  # a part's press ids strictly increase
        if waveforms:
            self._write_waveforms(press_id, int(row["position_id"]), waveforms)
        if not self._batch:
            self._batch_started = self._clock()
        self._batch.append(checked)
        self._batch_ids.add(press_id)
        path = self._parts_dir / part_name(self._batch[0].press_id)
        if len(self._batch) >= self.batch_presses or self._clock() - self._batch_started >= self.batch_s:
            self.flush()
        return path

    def flush(self) -> Path | None:
        """Write the batch as one part (atomically; fsync'd when the writer fsyncs); returns its path, or None
        when the batch is empty. A failed write drops the batch (its presses are not durable and are pressed
        again on resume) and raises the DataError naming the file."""
        if not self._batch:
            return None
        rows, self._batch, self._batch_ids = self._batch, [], set()
        first, last = rows[0].press_id, rows[-1].press_id
        path = self._parts_dir / part_name(first)
        # small files: column statistics and dictionaries cost time and help no reader
        sink = pa.BufferOutputStream()
        pq.write_table(
            self._encoder.table_of(rows), sink, write_statistics=False, use_dictionary=False, write_page_checksum=True
        )
        data = sink.getvalue().to_pybytes()
        write_bytes_durably(path, data, fsync=self.fsync, dir_fd=self._dir_fd)
        self._completed.update(r.press_id for r in rows)
        self._part_last[first] = last
        self.part_sha256[first] = hashlib.sha256(data).hexdigest()
        return path

    def _write_waveforms(self, press_id: int, position_id: int, waveforms: Mapping[str, np.ndarray]) -> Path:
        # every part carries the campaign's neatskin.* metadata (docs/datasets.md), with its press and position:
        # a waveform file copied out of its folder still says what it is
        meta = {**(self.schema.metadata or {}), **encode_metadata({"press_id": press_id, "position_id": position_id})}
        table = waveform_table(press_id, waveforms).replace_schema_metadata(meta)
        folder = self._waveforms_dir / f"position_id={position_id}"
        if folder not in self._position_dirs:
            created = not folder.exists()
            folder.mkdir(parents=True, exist_ok=True)
            if created and self.fsync:
                fsync_dir(folder.parent)
                fsync_dir(self.folder)
            self._position_dirs.add(folder)
        return write_durably(
            folder / part_name(press_id),
            lambda handle: pq.write_table(table, handle, write_page_checksum=True),
            fsync=self.fsync,
        )

    # ---- finalize ----------------------------------------------------------------------------

    def finalize(self) -> Path:
        """Write the batch, consolidate every durable press into presses.parquet (sorted by press_id, this
        writer's metadata, row groups of FINALIZE_BATCH rows) and then delete the parts. Crash-safe and
        idempotent: the consolidated file is replaced atomically before any part is deleted, and readers
        deduplicate a press found in both (`consolidate`)."""
        self.flush()
        return consolidate(self.folder, self.schema, self._part_last, fsync=self.fsync, dir_fd=self._dir_fd)

    def close(self) -> None:
        """Write the batch, then release the folder."""
        try:
            self.flush()
        finally:
            self._close_dir()

    def _close_dir(self) -> None:
        if self._dir_fd is not None:
            os.close(self._dir_fd)
            self._dir_fd = None

    def __enter__(self) -> CampaignWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is None:
            self.close()
            return
        try:  # leaving on an error: keep the batch if the disk lets us, but never hide the error
            self.close()
        except Exception as again:
            log.warning("the batch of presses was not written (resume presses them again): %s", again)

    def __del__(self) -> None:
        try:
            self._close_dir()  # never writes: a writer dropped without close() loses its batch, as a kill would
        except Exception:
            pass

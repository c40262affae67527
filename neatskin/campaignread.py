"""Reading a campaign folder's manifest.json and a presses parquet file, each with its one clear error: the ground-floor
reader that `datasets` (manifest, tables) and `skin.fit` share, since the import contract keeps `skin` from `datasets`.

Reading only: the writer, the schema and the folder's other files stay in `datasets`. pyarrow is imported where it is
used, so the ground floor stays light for `neatskin --help`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neatskin.errors import DataError
from neatskin.oserrors import os_error

if TYPE_CHECKING:
    import pyarrow as pa

MANIFEST_NAME = "manifest.json"
MANIFEST_RESTORE = "restore manifest.json from a backup (the presses are not in it and stay as they are)"
NOT_A_CAMPAIGN_FIX = "point at a campaign folder written by `neatskin campaign run`"


def read_manifest(folder: str | os.PathLike) -> dict[str, Any]:
    """The folder's manifest as a dict; DataError naming the file when it is missing, cannot be read (permission,
    a folder or a loop of links in its place), is not UTF-8, not JSON or not a JSON object."""
    path = Path(folder) / MANIFEST_NAME
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise DataError("no manifest.json in the campaign folder", file=str(path), fix=NOT_A_CAMPAIGN_FIX) from exc
    except OSError as exc:  # no read permission, a folder or a loop of links in the manifest's place
        if not Path(folder).is_dir():  # the "folder" is a file, or a link that leads back to itself
            raise DataError(
                f"not a campaign folder ({exc.strerror or exc})", file=str(folder), fix=NOT_A_CAMPAIGN_FIX
            ) from exc
        raise os_error(exc, "read", path, then=f"then {MANIFEST_RESTORE}") from exc
    except UnicodeDecodeError as exc:
        raise DataError(
            f"manifest.json is not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset {exc.start}): damaged",
            file=str(path),
            fix=MANIFEST_RESTORE,
        ) from exc
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise DataError(
            f"manifest.json is not valid JSON: {exc}",
            file=str(path),
            fix=MANIFEST_RESTORE,  # not update_manifest: it reads the manifest first, and fails on the same damage
        ) from exc
    if not isinstance(data, dict):
        raise DataError("manifest.json must hold a JSON object ({...}): damaged", file=str(path), fix=MANIFEST_RESTORE)
    return data


def unreadable_presses(exc: Exception, path: str | os.PathLike) -> DataError:
    """The one error for a presses file (or a dataset folder) pyarrow cannot read."""
    return DataError(
        f"cannot read the presses: {exc}",
        file=str(path),
        fix="run `neatskin dataset validate` on the folder to find the damaged file",
    )


def read_parquet(path: Path, columns: Sequence[str] | None = None) -> pa.Table:
    """One parquet file, its page checksums verified (a flipped bit is an error, not a changed value);
    metadata dropped. pyarrow's own error for a file it cannot read: `read_presses_file` names it."""
    import pyarrow.parquet as pq

    handle = pq.ParquetFile(path, page_checksum_verification=True)
    return handle.read(columns=columns, use_threads=False).replace_schema_metadata(None)


def read_presses_file(path: Path, columns: Sequence[str] | None = None) -> pa.Table:
    """`read_parquet` of a presses file, a file pyarrow cannot read (truncated, damaged, no permission) being the
    one DataError the dataset commands give for it."""
    import pyarrow as pa

    try:
        return read_parquet(path, columns)
    except (OSError, pa.ArrowException) as exc:
        raise unreadable_presses(exc, path) from exc

"""Validation of a press file's values and of the layout it names: non-finite and absurd values (the plausible
ranges are declared in schema.PLAUSIBLE_RANGES), and the layout recorded in a lone file's metadata, for the bounds
check. `validate.py` gathers these with its other checks."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from neatskin.datasets.scan import DatasetScan
from neatskin.datasets.schema import plausible_range
from neatskin.errors import ConfigError, DataError, Problem, raise_problems
from neatskin.layout import Layout, load_layout


def metadata_layout(folder: Path, metadata: dict, notes: list[str] | None) -> Layout | None:
    """The layout a press file's metadata names (`{path, sha256, source}`): the path relative to the file's
    folder or its parent (a part in presses/), else the source; the first whose sha256 matches the record."""
    from neatskin.datasets.writer import file_sha256

    ref = metadata.get("layout")
    ref = ref if isinstance(ref, dict) else {"path": ref} if isinstance(ref, str) else {}
    tried = []
    for name in (ref.get("path"), ref.get("source")):
        if not isinstance(name, str) or not name:
            continue
        for base in (folder, folder.parent) if not Path(name).is_absolute() else (Path("/"),):
            candidate = base / name
            if candidate in tried or not candidate.is_file():
                continue
            tried.append(candidate)
            try:
                if ref.get("sha256") and file_sha256(candidate) != ref["sha256"]:
                    continue
                return load_layout(candidate)
            except (ConfigError, DataError):  # an unreadable candidate is one not found
                continue
    if ref and notes is not None:
        notes.append(
            f"the bounds were not checked: the layout the metadata names ({ref.get('path')!r}) was not found "
            f"beside the file (or its sha256 differs); pass --layout SKIN.toml"
        )
    return None


def value_problems(scan: DatasetScan, has_ids: bool, ids_text: Callable, files_text: Callable) -> list[Problem]:
    """Non-finite values (+-inf; NaN is counted with the nulls by a scan) and values outside their plausible range."""
    problems: list[Problem] = []
    for found, what, fix in (
        (
            scan.nonfinite,
            "non-finite value(s) (inf or NaN)",
            "re-press those presses (drop them and resume the campaign) or drop the rows; a pair cut off by a pinched "
            "channel is +inf only with its open_circuit flag",
        ),
        (
            scan.implausible,
            "absurd value(s), outside the plausible range {span}",
            "check the units and the source of these rows; drop them or re-press",
        ),
    ):
        for column, bad in found.items():
            low, high, unit = plausible_range(column) or (-np.inf, np.inf, "")
            ids = np.concatenate(bad.press_ids) if bad.press_ids else np.array([])
            which = f" (press ids {ids_text(pd.Series(ids))})" if has_ids else ""
            examples = ", ".join(f"{v:g}" for v in bad.examples)
            problems.append(
                Problem(
                    f"{bad.count} {what.format(span=f'{low:g}..{high:g} {unit}')} in '{column}', e.g. {examples}"
                    f"{which}",
                    files_text(scan, bad.files),
                    column,
                    fix,
                )
            )
    return problems


def table_value_problems(table: pa.Table, source: str) -> list[Problem]:
    """What `validate` says of one in-memory press table's values: NaN in a column that may not be null, +-inf
    (a cut-off pair's +inf with its flag excepted) and values outside their plausible range."""
    from neatskin.datasets.scan import NullRows, scan_values
    from neatskin.datasets.schema import NULLABLE_COLUMNS

    scan = DatasetScan(files=[Path(source)])
    names = table.column_names
    ids = table.column("press_id").to_numpy(zero_copy_only=False).astype(float) if "press_id" in names else None
    for want in table.schema:
        if not pa.types.is_floating(want.type):
            continue
        scan_values(scan, table, want, ids, 0)
        if want.name in NULLABLE_COLUMNS:
            continue
        values = table.column(want.name).to_numpy(zero_copy_only=False).astype(float)
        nan = np.isnan(values)
        if nan.any():
            scan.nonfinite.setdefault(want.name, NullRows())  # NaN reported with the infinite values
            rows = scan.nonfinite[want.name]
            rows.count += int(nan.sum())
            rows.files.add(0)
            if ids is not None:
                rows.press_ids.append(ids[nan])
            rows.examples.extend(values[nan][: max(0, 3 - len(rows.examples))].tolist())
    return value_problems(scan, ids is not None, _ids_text, lambda s, files: source)


def refuse_bad_values(table: pa.Table, source: str, action: str) -> None:
    """Raise one DataError (every bad column, file, fix) before `action` uses values validation refuses."""
    problems = table_value_problems(table, source)
    fix = "; `neatskin dataset validate` lists every problem"
    raise_problems(
        [Problem(f"{action} refused: {p.message}", p.file, p.field, f"{p.fix}{fix}") for p in problems], DataError
    )


def _ids_text(series: pd.Series, limit: int = 8) -> str:
    values = sorted({int(v) for v in series if pd.notna(v)})
    text = ", ".join(str(v) for v in values[:limit])
    return text + (f", ... ({len(values)} in all)" if len(values) > limit else "")

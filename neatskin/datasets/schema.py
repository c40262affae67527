"""The press-row schema: column names and types as a function of the layout's electrode pairs, and
the `neatskin.`-prefixed key-value metadata (JSON values) that parquet files carry.

One row per press. Fixed columns first, then `R_ohm_{i}_{j}` for every pair (pressed resistance), then
`dR_ohm_{i}_{j}` (pressed minus baseline), both in the layout's pair order. Everything here is pure:
no files are read or written.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from neatskin.errors import DataError
from neatskin.layout import ElectrodePair

SCHEMA_VERSION = 1
META_PREFIX = "neatskin."

TIMESTAMP = pa.timestamp("us", tz="UTC")

BASE_FIELDS: tuple[pa.Field, ...] = (
    pa.field("campaign", pa.string(), nullable=False),
    pa.field("press_id", pa.int64(), nullable=False),
    pa.field("position_id", pa.int32(), nullable=False),
    pa.field("repeat", pa.int32(), nullable=False),
    pa.field("x_mm", pa.float64(), nullable=False),
    pa.field("y_mm", pa.float64(), nullable=False),
    pa.field("depth_mm", pa.float64(), nullable=False),
    pa.field("started_at", TIMESTAMP, nullable=False),
    pa.field("finished_at", TIMESTAMP, nullable=False),
    pa.field("fsr_onset_s", pa.float64()),
    pa.field("fsr_offset_s", pa.float64()),
    pa.field("fsr_peak_n", pa.float64()),
    pa.field("flags", pa.list_(pa.string()), nullable=False),
)
BASE_COLUMNS: tuple[str, ...] = tuple(f.name for f in BASE_FIELDS)
# columns a curated dataset may add beside the campaign's own: a merge names each row's source run
OPTIONAL_COLUMNS = frozenset({"source_run"})
NULLABLE_COLUMNS = frozenset(f.name for f in BASE_FIELDS if f.nullable)
_PAIR_COLUMN = re.compile(r"^(d?R)_ohm_(\d+)_(\d+)$")

# The plausible range of each float column, declared once (validation refuses a value outside it as absurd; merge,
# split, export and skin fit refuse what validation refuses). Wide on purpose: it catches 1e308 and a unit slip
# by 1e6, never a real skin. A pair's R may be +inf (cut off by a pinched channel) only with its open_circuit flag.
PLAUSIBLE_RANGES: dict[str, tuple[float, float, str]] = {
    "x_mm": (-10_000.0, 10_000.0, "mm"),
    "y_mm": (-10_000.0, 10_000.0, "mm"),
    "depth_mm": (0.0, 1_000.0, "mm"),
    "fsr_onset_s": (0.0, 1e7, "s"),
    "fsr_offset_s": (0.0, 1e7, "s"),
    "fsr_peak_n": (-1e4, 1e4, "N"),
    "R": (0.0, 1e9, "ohm"),  # every R_ohm_{i}_{j}
    "dR": (-1e9, 1e9, "ohm"),  # every dR_ohm_{i}_{j}
}
OPEN_CIRCUIT_FLAG = "open_circuit"  # the flag `open_circuit:{i}-{j}` a row with a cut-off pair carries
# The flags a pair cut off by a channel pinched shut leaves on its row (acquisition/demod.py): a measurement of the
# skin (the galvanostat at its compliance), not a fault of the rig; validate reports them as a note.
CUT_PAIR_FLAG_KINDS = (OPEN_CIRCUIT_FLAG, "clipped")


def plausible_range(column: str) -> tuple[float, float, str] | None:
    """(low, high, unit) of a float column of the press schema, None for a column without one."""
    pair = parse_pair_column(column)
    return PLAUSIBLE_RANGES.get(pair[0] if pair else column)


def r_column(pair: ElectrodePair) -> str:
    return f"R_ohm_{pair.i}_{pair.j}"


def dr_column(pair: ElectrodePair) -> str:
    return f"dR_ohm_{pair.i}_{pair.j}"


def pair_columns(pairs: Sequence[ElectrodePair]) -> tuple[list[str], list[str]]:
    """(R columns, dR columns) in pair order."""
    return [r_column(p) for p in pairs], [dr_column(p) for p in pairs]


def parse_pair_column(name: str) -> tuple[str, ElectrodePair] | None:
    """'dR_ohm_1_2' -> ('dR', ElectrodePair(1, 2)); None for any other column name."""
    match = _PAIR_COLUMN.match(name)
    if not match:
        return None
    i, j = int(match.group(2)), int(match.group(3))
    if not i < j:
        return None
    return match.group(1), ElectrodePair(i, j)


def normalise_pairs(pairs: Iterable[Any]) -> tuple[ElectrodePair, ...]:
    """Accept ElectrodePairs or (i, j) sequences (as stored in metadata); refuse empty or repeated pairs."""
    out = tuple(p if isinstance(p, ElectrodePair) else ElectrodePair(int(p[0]), int(p[1])) for p in pairs)
    if not out:
        raise DataError("no electrode pairs given", field="pairs", fix="pass layout.pairs")
    if len(set(out)) != len(out):
        raise DataError("an electrode pair is listed twice", field="pairs", fix="pass layout.pairs")
    return out


def press_schema(pairs: Sequence[ElectrodePair], metadata: Mapping[str, Any] | None = None) -> pa.Schema:
    """The arrow schema of a press table for these pairs, with encoded metadata (schema version and pairs
    are always added)."""
    pairs = normalise_pairs(pairs)
    r_cols, dr_cols = pair_columns(pairs)
    fields = list(BASE_FIELDS) + [pa.field(c, pa.float64(), nullable=False) for c in r_cols + dr_cols]
    meta = dict(metadata or {})
    meta["schema_version"] = SCHEMA_VERSION
    meta["pairs"] = [[p.i, p.j] for p in pairs]
    return pa.schema(fields, metadata=encode_metadata(meta))


def encode_metadata(metadata: Mapping[str, Any]) -> dict[bytes, bytes]:
    """{key: value} -> {b'neatskin.key': JSON bytes}. Values must be JSON-serialisable."""
    out = {}
    for key, value in metadata.items():
        try:
            text = json.dumps(value, sort_keys=True, default=_json_default)
        except TypeError as exc:
            raise DataError(
                f"metadata value for '{key}' is not JSON-serialisable: {exc}",
                field=key,
                fix="pass strings, numbers, lists or dicts",
            ) from exc
        out[(META_PREFIX + key).encode()] = text.encode()
    return out


def decode_metadata(raw: Mapping[bytes, bytes] | None) -> dict[str, Any]:
    """Parquet key-value metadata -> {key: value} for the `neatskin.` keys only (prefix stripped)."""
    out: dict[str, Any] = {}
    for key, value in (raw or {}).items():
        name = key.decode("utf-8", "replace")
        if name.startswith(META_PREFIX):
            try:
                out[name[len(META_PREFIX) :]] = json.loads(value)
            except ValueError:
                out[name[len(META_PREFIX) :]] = value.decode("utf-8", "replace")
    return out


def _json_default(value: Any) -> Any:
    if isinstance(value, (_dt.datetime, _dt.date)):
        return value.isoformat()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, ElectrodePair):
        return [value.i, value.j]
    return str(value)


# ---- rows -> arrow -----------------------------------------------------------------------------------


def _timestamp_us(value: Any, key: str) -> int:
    """datetime (aware, or naive meaning UTC), numpy datetime64 or epoch seconds -> epoch microseconds."""
    if isinstance(value, _dt.datetime):
        if value.tzinfo is None:
            value = value.replace(tzinfo=_dt.UTC)
        delta = value - _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)
        return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds
    if isinstance(value, np.datetime64):
        return int(value.astype("datetime64[us]").astype(np.int64))
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        if math.isfinite(float(value)):
            return int(round(float(value) * 1e6))
    raise DataError(
        f"'{key}' must be a datetime or epoch seconds, got {value!r}",
        field=key,
        fix="pass datetime.now(timezone.utc) or time.time()",
    )


_INT_RANGES = {pa.int32(): (-(2**31), 2**31 - 1), pa.int64(): (-(2**63), 2**63 - 1)}


@dataclass(frozen=True)
class CheckedRow:
    """One press row with every key checked and every value converted to what its column stores (epoch
    microseconds for timestamps); `pair_values_ohm` holds R then dR in the layout's pair order."""

    values: tuple[Any, ...]  # one per BASE_FIELDS entry
    pair_values_ohm: np.ndarray

    @property
    def press_id(self) -> int:
        return int(self.values[_PRESS_ID])


_PRESS_ID = BASE_COLUMNS.index("press_id")


class RowEncoder:
    """Turns press-row dicts into arrow tables of a fixed schema, checking every key.

    A row gives each fixed column by name, and the pair values either per column (`R_ohm_1_2`, ...) or as
    two arrays `R_ohm` and `dR_ohm` of shape (pairs,) in the layout's pair order. `fsr_*` may be absent
    (null: a protocol without an FSR) and `flags` may be absent (no flags).

    `check(row)` does every check of one row (the first problem raises, in column order); `table_of(checked)`
    builds one arrow array per column for many checked rows at once, so a batch of presses costs about what
    one press did. `table(row)` is the one-row table, the same as `table_of([check(row)])`.
    """

    def __init__(self, schema: pa.Schema) -> None:
        self.schema = schema
        self.pair_names = [f.name for f in schema][len(BASE_FIELDS) :]
        self.n_pairs = len(self.pair_names) // 2
        self._known = set(BASE_COLUMNS) | set(self.pair_names) | {"R_ohm", "dR_ohm"}

    def table(self, row: Mapping[str, Any]) -> pa.Table:
        return self.table_of([self.check(row)])

    def rows_table(self, rows: Sequence[Mapping[str, Any]]) -> pa.Table:
        """Many rows as one table; the first bad row raises what `table(row)` would."""
        return self.table_of([self.check(row) for row in rows])

    def check(self, row: Mapping[str, Any]) -> CheckedRow:
        unknown = sorted(set(row) - self._known)
        if unknown:
            raise DataError(
                f"unknown key(s) in press row: {', '.join(unknown)}",
                field=unknown[0],
                fix="use the schema's column names (neatskin.datasets.schema.press_schema)",
            )
        missing = [c for c in BASE_COLUMNS if c not in row and c not in NULLABLE_COLUMNS and c != "flags"]
        if missing:
            raise DataError(f"press row lacks {', '.join(missing)}", field=missing[0], fix="give every fixed column")
        values = tuple(_column_value(f, row.get(f.name)) for f in BASE_FIELDS)
        return CheckedRow(values, self._pair_values(row))

    def table_of(self, rows: Sequence[CheckedRow]) -> pa.Table:
        """The table of checked rows, one arrow array per column."""
        arrays: list[pa.Array] = []
        for k, f in enumerate(BASE_FIELDS):
            column = [r.values[k] for r in rows]
            try:
                arrays.append(pa.array(column, f.type))
            except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
                for value in column:  # name the value that does not fit, as one row would
                    _fits(f, value)
                raise
        pairs = np.empty((len(self.pair_names), len(rows)), dtype=np.float64)
        for k, r in enumerate(rows):
            pairs[:, k] = r.pair_values_ohm
        arrays.extend(pa.array(column, pa.float64()) for column in pairs)
        return pa.Table.from_arrays(arrays, schema=self.schema)

    def _pair_values(self, row: Mapping[str, Any]) -> np.ndarray:
        if "R_ohm" in row or "dR_ohm" in row:
            parts = []
            for key in ("R_ohm", "dR_ohm"):
                arr = np.asarray(row.get(key), dtype=np.float64).reshape(-1)
                if arr.shape != (self.n_pairs,):
                    raise DataError(
                        f"'{key}' has {arr.size} values, the layout has {self.n_pairs} pairs",
                        field=key,
                        fix="give one value per pair of layout.pairs, in that order",
                    )
                parts.append(arr)
            return np.concatenate(parts)
        missing = [c for c in self.pair_names if c not in row]
        if missing:
            raise DataError(
                f"press row lacks {len(missing)} pair column(s), first {missing[0]}",
                field=missing[0],
                fix="give R_ohm_i_j and dR_ohm_i_j for every pair, or arrays R_ohm and dR_ohm",
            )
        return np.array([row[c] for c in self.pair_names], dtype=np.float64)


def _column_value(f: pa.Field, value: Any) -> Any:
    """A row's value for column `f`, converted as stored and checked to fit (DataError naming the field)."""
    if f.name in ("started_at", "finished_at"):
        value = _timestamp_us(value, f.name)
    elif f.name == "flags":
        return [] if value is None else [str(v) for v in value]
    elif value is None:
        if not f.nullable:
            raise DataError(f"'{f.name}' is None", field=f.name, fix="give a value")
        return None
    elif f.name == "campaign":
        return str(value)
    elif pa.types.is_integer(f.type):
        value = int(value)
    else:
        return float(value)
    _fits(f, value)
    return value


def _fits(f: pa.Field, value: Any) -> None:
    """Raise the DataError arrow's own conversion gives when an integer (or timestamp) does not fit `f`."""
    low, high = _INT_RANGES.get(f.type, _INT_RANGES[pa.int64()])
    if value is None or not isinstance(value, int) or low <= value <= high:
        return
    try:
        pa.array([value], f.type)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError) as exc:
        raise DataError(
            f"'{f.name}' = {value!r} does not fit {f.type}: {exc}",
            field=f.name,
            fix=f"give a value of type {f.type}",
        ) from exc

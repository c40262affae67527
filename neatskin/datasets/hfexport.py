"""`dataset export --format hf`: a dataset in the layout the Hugging Face Hub reads. Parquet data files per split
(split by position, as `dataset split`), the physical limit as a second config, the input files, and a README.md
dataset card whose YAML front matter holds `license`, `configs` and `dataset_info` (the features), whose text
gives the protocol, the skin, the scene and the paper's citation. Nothing in it names the recording machine:
metadata, manifest and inputs pass through `privacy.scrub`.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from neatskin.datasets.cardtext import card_body
from neatskin.datasets.curate import export_source_manifest, split_positions
from neatskin.datasets.curation import empty_output, flagged_mask
from neatskin.datasets.durable import write_bytes_durably
from neatskin.datasets.manifest import resolve_manifest_path
from neatskin.datasets.privacy import recorded_hosts, scrub, scrub_text
from neatskin.datasets.reader import read_press_table
from neatskin.datasets.schema import decode_metadata, encode_metadata
from neatskin.datasets.tables import write_table_durably
from neatskin.errors import DataError

DEFAULT_LICENSE = "cc-by-4.0"
DEFAULT_TEST_FRACTION = 0.2
PHYSICAL_LIMIT_NAME = "physical_limit.parquet"
_PLAIN = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
_YAML_WORDS = {"true", "false", "null", "yes", "no", "on", "off", "y", "n", "~"}


# ---- YAML: the card's front matter, written here (no YAML library needed to write a few nested lists) ----


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return json.dumps(float(value))
    text = str(value)
    if _PLAIN.match(text) and text.lower() not in _YAML_WORDS:
        return text
    return json.dumps(text, ensure_ascii=False)  # a JSON string is a YAML double-quoted scalar


def to_yaml(value: Any, indent: int = 0) -> str:
    """Block-style YAML of dicts, lists and scalars (strings quoted unless plainly safe)."""
    pad = " " * indent
    lines: list[str] = []
    if isinstance(value, dict):
        for key, item in value.items():
            if isinstance(item, (dict, list)) and item:
                lines.append(f"{pad}{_scalar(key)}:")
                lines.append(to_yaml(item, indent + (0 if isinstance(item, list) else 2)))
            else:
                lines.append(f"{pad}{_scalar(key)}: {_scalar(item) if not isinstance(item, (dict, list)) else '[]'}")
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, (dict, list)) and item:
                body = to_yaml(item, indent + 2).splitlines()
                lines.append(f"{pad}- {body[0].lstrip()}")
                lines.extend(body[1:])
            else:
                lines.append(f"{pad}- {_scalar(item)}")
    else:
        lines.append(f"{pad}{_scalar(value)}")
    return "\n".join(lines)


def hf_feature(field: pa.Field) -> dict[str, Any]:
    """A column as the card's `dataset_info.features` entry (the Hub's names for arrow types)."""
    t = field.type
    if pa.types.is_list(t) or pa.types.is_large_list(t):
        return {"name": field.name, "sequence": _dtype(t.value_type)}
    return {"name": field.name, "dtype": _dtype(t)}


def _dtype(t: pa.DataType) -> str:
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return "string"
    if pa.types.is_timestamp(t):
        return f"timestamp[{t.unit}, tz={t.tz}]" if t.tz else f"timestamp[{t.unit}]"
    if pa.types.is_boolean(t):
        return "bool"
    if pa.types.is_floating(t):
        return f"float{t.bit_width}"  # arrow prints float64 as "double"; the Hub's Value says float64
    return str(t)  # int32, int64, ... are the Hub's names too


# ---- the export ------------------------------------------------------------------------------------------------


def _clean_table(table: pa.Table, hosts: set[str]) -> pa.Table:
    """The table with its `neatskin.` metadata scrubbed (every other key, pandas' included, dropped)."""
    meta = scrub(decode_metadata(table.schema.metadata), hosts)
    return table.replace_schema_metadata(encode_metadata(meta))


def _write(out: Path, relative: str, data: bytes) -> str:
    path = out / relative
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_durably(path, data)
    return relative


def export_hf(
    path: str | os.PathLike,
    out: str | os.PathLike,
    *,
    license: str = DEFAULT_LICENSE,
    test_fraction: float = DEFAULT_TEST_FRACTION,
    seed: int = 0,
    drop_flagged: bool = False,
) -> Path:
    """Write the dataset at `path` (campaign folder or presses file) as a Hugging Face dataset folder `out`."""
    path, out = Path(path), Path(out)
    empty_output(out)
    if not license.strip() or any(c.isspace() for c in license.strip()):
        raise DataError(f"licence {license!r}", field="--license", fix="give an SPDX-style id, e.g. cc-by-4.0")
    folder = path if path.is_dir() else path.parent
    manifest = export_source_manifest(path)  # a campaign folder's damaged manifest stops the export here
    table = read_press_table(path)
    if drop_flagged:
        table = table.filter(pa.array(~flagged_mask(table)))
    if table.num_rows == 0:
        raise DataError("the dataset holds no presses", file=str(path), fix="export a campaign that recorded presses")
    hosts = recorded_hosts(manifest)
    table = _clean_table(table, hosts)
    positions = table.column("position_id").to_numpy()
    train_ids, test_ids = split_positions(positions, test_fraction, seed)
    out.mkdir(parents=True, exist_ok=True)
    splits: dict[str, int] = {}
    for name, ids in (("train", train_ids), ("test", test_ids)):
        part = table.filter(pa.array(np.isin(positions, ids)))
        write_table_durably(out / "data" / f"{name}-00000-of-00001.parquet", part)
        splits[name] = part.num_rows
    configs = [
        {
            "config_name": "presses",
            "default": True,
            "data_files": [{"split": n, "path": f"data/{n}-*.parquet"} for n in splits],
        }
    ]
    info = [
        {
            "config_name": "presses",
            "features": [hf_feature(f) for f in table.schema],
            "splits": [{"name": n, "num_examples": k} for n, k in splits.items()],
        }
    ]
    limit_rows = _export_limit(folder, out, hosts)
    if limit_rows is not None:
        limit_schema, n_limit = limit_rows
        configs.append(
            {
                "config_name": "physical_limit",
                "data_files": [{"split": "positions", "path": "physical_limit/positions-*.parquet"}],
            }
        )
        info.append(
            {
                "config_name": "physical_limit",
                "features": [hf_feature(f) for f in limit_schema],
                "splits": [{"name": "positions", "num_examples": n_limit}],
            }
        )
    inputs = _export_inputs(folder, manifest, out, hosts)
    clean_manifest = scrub(manifest, hosts)
    if clean_manifest:
        _write(out, "neatskin_manifest.json", json.dumps(clean_manifest, indent=2, default=str).encode())
    front = {
        "license": license.strip(),
        "pretty_name": f"NeatSkin presses: {manifest.get('campaign') or _first(table, 'campaign')}",
        "tags": ["tactile-sensing", "soft-robotics", "electrical-impedance-tomography", "neatskin"],
        "size_categories": [_size_category(table.num_rows)],
        "configs": configs,
        "dataset_info": info,
    }
    # README.md: the YAML front matter, then what a reader needs to use the data and to cite it
    body = card_body(front, table, manifest, folder, splits, test_fraction, seed, inputs, limit_rows is not None)
    card = f"---\n{to_yaml(front)}\n---\n\n" + body
    _write(out, "README.md", scrub_text(card, hosts).encode())
    return out


def _first(table: pa.Table, column: str) -> str:
    return str(table.column(column)[0].as_py()) if table.num_rows else "?"


def _size_category(n: int) -> str:
    for limit, label in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M")):
        if n < limit:
            return label
    return "n>1M"


def _export_limit(folder: Path, out: Path, hosts: set[str]) -> tuple[pa.Schema, int] | None:
    source = folder / PHYSICAL_LIMIT_NAME
    if not source.is_file():
        return None
    import pyarrow.parquet as pq

    limit = _clean_table(pq.read_table(source), hosts)
    write_table_durably(out / "physical_limit" / "positions-00000-of-00001.parquet", limit)
    return limit.schema, limit.num_rows


def _export_inputs(folder: Path, manifest: dict[str, Any], out: Path, hosts: set[str]) -> list[str]:
    """The input TOML files the manifest names, copied as inputs/<key>.toml (scrubbed of local paths)."""
    written = []
    for key in ("protocol", "layout", "wiring", "printer"):
        source = resolve_manifest_path(folder, manifest, key) if manifest else None
        if source is not None and source.is_file():
            text = scrub_text(source.read_text(encoding="utf-8"), hosts)
            written.append(_write(out, f"inputs/{key}.toml", text.encode()))
    return written


def read_card_front_matter(card: str) -> str:
    """The YAML between the card's first two `---` lines (for checks and tests)."""
    if not card.startswith("---\n"):
        raise DataError("the card does not start with YAML front matter", field="README.md", fix="export again")
    return card[4 : card.index("\n---\n", 4)]

"""Validation of a campaign's manifest against its data: the counts, the seed, the pairs and the layout the files'
metadata record, the campaign the rows belong to, and the layout the manifest names (loaded for the bounds check).
`validate.py` gathers these with its other checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from neatskin.datasets.manifest import resolve_manifest_path
from neatskin.datasets.scan import DatasetScan
from neatskin.errors import ConfigError, Problem
from neatskin.layout import ElectrodePair, Layout, load_layout


def manifest_layout(folder: Path, manifest: dict, manifest_file: str, problems: list[Problem]) -> Layout | None:
    """The layout the manifest names, for the bounds check; None (a Problem added) when it cannot be loaded."""
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


def manifest_problems(
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

"""The text of an exported dataset's card (README.md below its YAML): the protocol, the skin, the scene, the
splits, the columns, how to load it and how to cite the paper. Pure: from the table, the manifest and the layout."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from neatskin.datasets.manifest import resolve_manifest_path

CITATION = """@misc{judd_neatskin,
  title  = {NeatSkin: A Discrete Impedance Tomography Skin Sensor},
  author = {Judd, Euan and Digumarti, Krishna Manaswi and Rossiter, Jonathan and Hauser, Helmut}
}"""
COLUMN_TEXT = {
    "campaign": "the campaign's name (from its protocol)",
    "source_run": "the run (campaign folder) the row came from, in a merged dataset",
    "press_id": "the press's id, unique per row",
    "position_id": "the commanded position's id; repeats of a position share it (split by it)",
    "repeat": "the repeat index at the position",
    "x_mm": "commanded x of the press (mm, skin frame): the label",
    "y_mm": "commanded y of the press (mm, skin frame): the label",
    "depth_mm": "commanded press depth (mm)",
    "started_at": "press record start (UTC)",
    "finished_at": "press record end (UTC)",
    "fsr_onset_s": "force sensor onset, s after the record began (null when not detected)",
    "fsr_offset_s": "force sensor offset, s after the record began (null when not detected)",
    "fsr_peak_n": "force sensor peak (N)",
    "flags": 'what went wrong with the press, if anything (empty: nothing); read it as df["flags"]: '
    "pandas' df.flags is the DataFrame's own attribute",
}


def run_manifests(manifest: dict[str, Any], table: pa.Table) -> list[dict[str, Any]]:
    """The manifests of the runs behind the dataset: its own, or a merge's sources' (from the metadata)."""
    if isinstance(manifest.get("protocol_as_run"), dict):
        return [manifest]
    from neatskin.datasets.schema import decode_metadata

    sources = decode_metadata(table.schema.metadata).get("merged_from") or []
    return [s["manifest"] for s in sources if isinstance(s, dict) and isinstance(s.get("manifest"), dict)]


def _protocol_lines(manifest: dict[str, Any], runs: int = 1) -> list[str]:
    run = manifest.get("protocol_as_run")
    if not isinstance(run, dict):
        return [
            "The manifest records no protocol (a split dataset, or one written by hand: see `neatskin_manifest.json`)."
        ]
    campaign, positions, press = run.get("campaign", {}), run.get("positions", {}), run.get("press", {})
    excitation, acq, record = run.get("excitation", {}), run.get("acquisition", {}), run.get("record", {})
    lines = [
        f"- campaign `{campaign.get('name')}`, seed {campaign.get('seed')}: {campaign.get('description', '')}".rstrip(
            ": "
        ),
        f"- positions: {positions.get('count')} ({positions.get('strategy')}), {press.get('repeats')} presses each, "
        f"order `{press.get('order')}`",
        f"- press: {press.get('depth_mm')} mm deep with a {press.get('probe_diameter_mm')} mm probe, held "
        f"{press.get('hold_s')} s",
        f"- excitation: {excitation.get('amplitude_a')} A at {excitation.get('frequency_hz')} Hz; acquisition "
        f"{acq.get('rate_hz')} Hz, demodulation `{acq.get('demodulation')}`",
        f"- raw waveforms recorded: {'yes (not in this export: features only)' if record.get('waveforms') else 'no'}",
    ]
    if runs > 1:
        lines.insert(0, f"A merge of {runs} runs (the `source_run` column names each row's); the first run's protocol:")
    return lines + ["", "The protocol file as run is `inputs/protocol.toml` when present."]


def _skin_lines(manifest: dict[str, Any], folder: Path, table: pa.Table) -> list[str]:
    n_pairs = sum(1 for n in table.column_names if n.startswith("dR_ohm_"))
    path = resolve_manifest_path(folder, manifest, "layout") if manifest else None
    if path is None or not path.is_file():
        return [f"{n_pairs} electrode pairs; the layout file is not part of the dataset."]
    from neatskin.layout import load_layout

    try:
        layout = load_layout(path)
    except Exception:  # a card still gets written when a layout no longer loads: say so instead
        return [f"{n_pairs} electrode pairs; the layout `inputs/layout.toml` does not load with this toolkit."]
    x0, y0, x1, y1 = layout.bounds_mm
    return [
        f"`{layout.name}`: {layout.description}".rstrip(": "),
        f"- {len(layout.electrodes)} electrodes, {len(layout.channels)} fluid channels, {n_pairs} measured pairs; "
        f"extent {x1 - x0:g} x {y1 - y0:g} mm (`inputs/layout.toml`)",
    ]


def _scene_lines(manifest: dict[str, Any]) -> list[str]:
    rig = manifest.get("rig")
    if not isinstance(rig, dict):
        return ["The manifest does not say which rig recorded the data."]
    if rig.get("kind") == "dry-run":
        skin = rig.get("skin") or {}
        return [
            "**Simulated (a dry run):** a simulated printer, skin and DAQ; not a physical sensor. "
            f"Scene preset `{skin.get('preset')}`, fidelity `{skin.get('fidelity')}`, signal `{skin.get('signal')}`, "
            f"noise {'on' if skin.get('noise') else 'off'}; placement error {skin.get('placement_error_mm')} mm, "
            f"depth jitter {skin.get('depth_jitter_mm')} mm, fluid drift {skin.get('temperature_drift_k_per_h')} K/h. "
            "Every scene parameter is in `neatskin_manifest.json` (`rig.skin`).",
        ]
    if rig.get("daq") == "simulated":  # hardware in the loop: the printer's motion is real, the signals are not
        return [
            f"**A real printer with a simulated skin and DAQ** (printer on `{rig.get('printer')}`): the motion is "
            "the printer's, every resistance and force is simulated; not a physical sensor."
        ]
    return [f"**Recorded on the real rig** (DAQ `{rig.get('daq')}`)."]


def _merged_scene_lines(manifest: dict[str, Any], table: pa.Table, first: dict[str, Any]) -> list[str]:
    """A merge's scene: each source's share of the exported presses and its rig in words (the manifest's
    `source_rigs`, the rows' `source_run`), then each source's own scene; merge refuses to mix rigs unless
    --allow-mixed-rigs, so a mixed merge says so first."""
    from neatskin.datasets.rigkind import MIXED

    entries = [e for e in manifest.get("source_rigs") or [] if isinstance(e, dict)]
    if not entries:
        return _scene_lines(first)  # a merge written before merge recorded its sources' rigs
    counts: dict[str, int] = {}
    if "source_run" in table.column_names:
        for run, n in zip(*np.unique(table.column("source_run").to_numpy(zero_copy_only=False), return_counts=True)):
            counts[str(run)] = int(n)
    shares = ", ".join(f"{counts.get(str(e.get('run')), 0):,} presses {e.get('description')}" for e in entries)
    rig = manifest.get("rig")
    mixed = isinstance(rig, dict) and rig.get("kind") == MIXED
    lines = [
        ("**Mixed rigs (merged with --allow-mixed-rigs):** " if mixed else "A merge of one rig's runs: ")
        + shares
        + ".",
        "",
    ]
    for entry in entries:
        scene = _scene_lines({"rig": entry.get("rig")})  # the source manifest's rig, as merge recorded it
        scene[0] = scene[0].replace("(`rig.skin`)", "(`source_rigs`, each source's `rig.skin`)")
        lines.append(f"- run `{entry.get('run')}` ({counts.get(str(entry.get('run')), 0):,} presses): {scene[0]}")
    return lines


def card_body(
    front: dict[str, Any],
    table: pa.Table,
    manifest: dict[str, Any],
    folder: Path,
    splits: dict[str, int],
    test_fraction: float,
    seed: int,
    inputs: list[str],
    has_limit: bool,
) -> str:
    """The card's text below its YAML front matter (hfexport writes both): what a reader needs to use the data and
    to cite it."""
    runs = run_manifests(manifest, table)
    first = runs[0] if runs else manifest
    flagged = int(pc.sum(pc.greater(pc.list_value_length(table.column("flags")), 0)).as_py() or 0)
    positions = len(np.unique(table.column("position_id").to_numpy()))
    lines = [
        f"# {front['pretty_name']}",
        "",
        f"{table.num_rows:,} presses at {positions:,} positions on a NeatSkin fluid-channel skin, recorded by "
        "neatskin-rig: a 3D printer presses a probe into the skin, a DAQ measures the resistance of every "
        "electrode pair, and each press is one row: its commanded position (the label) and the pressed "
        f"resistance `R_ohm_i_j` and its change from baseline `dR_ohm_i_j` per pair. {flagged:,} presses carry "
        "flags.",
        "",
        "## Protocol",
        "",
        *_protocol_lines(first, len(runs)),
        "",
        "## Skin",
        "",
        *_skin_lines(manifest, folder, table),
        "",
        "## Scene",
        "",
        *(_merged_scene_lines(manifest, table, first) if manifest.get("kind") == "merge" else _scene_lines(first)),
        "",
        "## Splits",
        "",
        f"By position: {round(100 * test_fraction)} % of the positions (seed {seed}) are `test`, the rest `train`; "
        "every repeat of a position lands in one split, so `test` measures presses at positions never seen in "
        f"training. train: {splits.get('train', 0):,} rows, test: {splits.get('test', 0):,} rows.",
    ]
    if has_limit:
        lines += [
            "",
            "The `physical_limit` config gives, per pressed position, the Cramér-Rao bound on the position error "
            "(`crb_mm`: electronics noise only; `crb_nuisance_mm`, when present: with the scene's depth, drift "
            "and placement as nuisances). Their meaning is in the file's `neatskin.physical_limit` metadata.",
        ]
    lines += [
        "",
        "## Columns",
        "",
        "| column | meaning |",
        "|---|---|",
        *[f"| `{c}` | {COLUMN_TEXT[c]} |" for c in table.column_names if c in COLUMN_TEXT],
        "| `R_ohm_i_j` | pressed resistance of electrode pair (i, j), ohm |",
        "| `dR_ohm_i_j` | pressed minus baseline resistance of pair (i, j), ohm |",
        "",
        "## Loading",
        "",
        "```python",
        "from datasets import load_dataset",
        'ds = load_dataset("parquet", data_files={"train": "data/train-*.parquet", "test": "data/test-*.parquet"})',
        "# or: import pandas as pd; df = pd.read_parquet('data/train-00000-of-00001.parquet'); df['flags']",
        "```",
        "",
        "Each parquet file keeps the toolkit's `neatskin.*` metadata (pairs, seed, software version, input "
        "file hashes); host names and local paths were removed on export.",
        "",
        "## Files",
        "",
        *[f"- `{name}`" for name in (*inputs, "neatskin_manifest.json") if name],
        "",
        "## Citation",
        "",
        "The sensor and the campaign protocol are those of the NeatSkin paper:",
        "",
        "```bibtex",
        CITATION,
        "```",
        "",
        f"Licence: `{front['license']}`.",
        "",
    ]
    return "\n".join(lines)

"""The monitor's view of a campaign folder as one JSON-ready snapshot: status, counts, rate and ETA, pressed
positions, the last press against the skin model, per-pair signal quality, baseline drift, printer position
and the wire log's tail (those two read by `wiretail`).

Reads only the campaign folder, and its presses only through neatskin.datasets.reader (file by file, so a
snapshot re-reads only the parts that landed since the last one). Works on a running, killed or finished
campaign: every file may be missing or half-written, and each section then says so instead of failing.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from neatskin.datasets.lock import lock_state
from neatskin.datasets.manifest import read_manifest
from neatskin.datasets.paths import part_press_id
from neatskin.datasets.reader import press_files, read_presses
from neatskin.errors import NeatskinError
from neatskin.monitor.wiretail import WIRE_LOG, wire_tail, wire_text
from neatskin.rig.control import read_request, read_state

log = logging.getLogger(__name__)

DRIFT_MAX_POINTS = 600  # presses per drift line sent to the page (a 2,800-press campaign is strided)
RATE_WINDOW_PRESSES = 20  # rate over the last presses, so a pause or a resume a day later does not skew it


def _finite(values: Any) -> list[float | None]:
    """A JSON-safe list: NaN and inf become None (JSON has neither)."""
    return [float(v) if math.isfinite(float(v)) else None for v in np.ravel(values)]


def _plain(df: pd.DataFrame) -> pd.DataFrame:
    """Without attrs: pandas deep-copies df.attrs (the dataset metadata) on every column access."""
    df.attrs = {}
    return df


@dataclass
class PressCache:
    """Presses read so far. The whole table is read through the reader once (and again only when a file
    already read changed or went away, as when parts are consolidated); parts that land later are read
    one by one and appended."""

    files: dict[Path, tuple[int, int]] = field(default_factory=dict)
    table: pd.DataFrame = field(default_factory=pd.DataFrame)

    def read(self, folder: Path) -> pd.DataFrame:
        try:
            paths = press_files(folder)
        except NeatskinError:
            paths = []
        fresh: dict[Path, tuple[int, int]] = {}
        for path in paths:
            if part_press_id(path) is not None:  # a durable part is renamed into place whole and never rewritten
                fresh[path] = (0, 0)
                continue
            try:
                st = path.stat()
            except OSError:
                continue  # consolidated while we listed
            fresh[path] = (st.st_size, st.st_mtime_ns)
        if fresh == self.files:
            return self.table
        added = [p for p in fresh if p not in self.files]
        if not fresh:
            self.files, self.table = {}, pd.DataFrame()
        elif self.table.empty or any(fresh.get(p) != stamp for p, stamp in self.files.items()):
            try:
                self.table = _plain(read_presses(folder))
                self.files = fresh
            except NeatskinError as exc:
                log.info("presses not readable yet: %s", exc)
        else:
            frames = [self.table]
            for path in added:
                try:
                    frames.append(_plain(read_presses(path)))
                    self.files[path] = fresh[path]
                except NeatskinError as exc:
                    log.info("skipping %s for now: %s", path, exc)
            df = pd.concat(frames, ignore_index=True)
            self.table = df.drop_duplicates("press_id").sort_values("press_id", kind="stable").reset_index(drop=True)
        return self.table


def _pairs(df: pd.DataFrame, manifest: dict[str, Any]) -> list[tuple[int, int]]:
    pairs = manifest.get("pairs")
    if isinstance(pairs, list) and pairs:
        return [(int(p[0]), int(p[1])) for p in pairs]
    return [(int(c.split("_")[2]), int(c.split("_")[3])) for c in df.columns if c.startswith("dR_ohm_")]


def layout_view(folder: Path) -> dict[str, Any] | None:
    """Junctions, channels and electrodes of the campaign's own layout copy (inputs/layout.toml)."""
    from neatskin.layout import load_layout

    path = folder / "inputs" / "layout.toml"
    try:
        layout = load_layout(path)
    except (NeatskinError, OSError, ValueError) as exc:
        log.info("no layout view: %s", exc)
        return None
    xy = layout.xy_mm
    return {
        "name": layout.name,
        "junctions": xy.round(4).tolist(),
        "channels": [[c.a, c.b, c.width_mm] for c in layout.channels],
        "electrodes": [[e.number, e.junction] for e in layout.electrodes],
        "bounds_mm": list(layout.bounds_mm),
    }


class ModelCache:
    """The ideal skin model of the campaign's layout (built once), for what a press at (x, y) should give."""

    def __init__(self) -> None:
        self._model: Any = None
        self._failed = False

    def expected_dr_ohm(self, folder: Path, manifest: dict[str, Any], x_mm: float, y_mm: float, depth_mm: float):
        if self._model is None and not self._failed:
            try:
                from neatskin.layout import load_layout
                from neatskin.skin.model import SkinModel

                press = (manifest.get("protocol_as_run") or {}).get("press") or {}
                scene = (manifest.get("protocol_as_run") or {}).get("scene") or {}
                radius = float(press.get("probe_diameter_mm", 5.5)) / 2
                fidelity = str(scene.get("fidelity", "deformation"))
                self._model = SkinModel(load_layout(folder / "inputs" / "layout.toml"), fidelity, radius)
            except (NeatskinError, OSError, ValueError, TypeError) as exc:
                log.info("no skin model for the expected dR: %s", exc)
                self._failed = True
        if self._model is None:
            return None
        pressed = np.asarray(self._model.pair_resistance_ohm(x_mm, y_mm, depth_mm)).reshape(-1)
        return pressed - np.asarray(self._model.baseline_pair_resistance_ohm).reshape(-1)


def quality(df: pd.DataFrame, pairs: Sequence[tuple[int, int]]) -> dict[str, Any]:
    """Per pair: presses with a clipped, open-circuit or other flag; FSR misses and retries over the campaign."""
    kinds = ("clipped", "open_circuit", "dc_offset", "no_samples")
    labels = [f"{i}-{j}" for i, j in pairs]
    counts = {k: dict.fromkeys(labels, 0) for k in kinds}
    fsr = {"missed": 0, "retried": 0, "multiple": 0}
    for flags in df.get("flags", pd.Series([], dtype=object)):
        seen = set()
        for flag in flags:
            name, _, pair = str(flag).partition(":")
            if name in counts and pair in counts[name] and (name, pair) not in seen:
                counts[name][pair] += 1
                seen.add((name, pair))
            elif name == "fsr_missed":
                fsr["missed"] += 1
            elif name == "fsr_retry":
                fsr["retried"] += 1
            elif name == "fsr_multiple":
                fsr["multiple"] += 1
    return {"pairs": labels, "counts": {k: [counts[k][p] for p in labels] for k in kinds}, "fsr": fsr}


def rate_and_eta(df: pd.DataFrame, planned: int) -> tuple[float | None, float | None]:
    """(presses per hour over the last presses, seconds left at that rate), None where unknown."""
    if len(df) < 2 or "finished_at" not in df:
        return None, None
    done = pd.to_datetime(df["finished_at"], utc=True).sort_values().iloc[-RATE_WINDOW_PRESSES:]
    span_s = (done.iloc[-1] - done.iloc[0]).total_seconds()
    if span_s <= 0:
        return None, None
    per_s = (len(done) - 1) / span_s
    return per_s * 3600.0, max(planned - len(df), 0) / per_s


def _since_last_s(df: pd.DataFrame) -> float | None:
    """Seconds since the last durable press finished (a running campaign that stops landing presses was killed)."""
    if df.empty or "finished_at" not in df:
        return None
    last = pd.to_datetime(df["finished_at"], utc=True).max()
    return max(0.0, (pd.Timestamp.now(tz="UTC") - last).total_seconds())


RESULT_FILES = ("report.md", "baselines.csv")  # with every PNG at the folder's top: the report's plots


def result_links(folder: Path) -> list[dict[str, str]]:
    """The report and its plots, as links the page shows (served read-only under /files/)."""
    names = [n for n in RESULT_FILES if (folder / n).is_file()]
    try:
        names += sorted(p.name for p in folder.glob("*.png") if p.is_file())
    except OSError:
        pass
    return [{"name": n, "href": f"/files/{n}"} for n in names]


class CampaignView:
    """Snapshots of one campaign folder; keeps caches between polls."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self._presses = PressCache()
        self._model = ModelCache()
        self._layout: dict[str, Any] | None = None
        self._cached_stamp: tuple[object, ...] | None = None
        self._cached_json = b""

    def _stamp(self) -> tuple[object, ...]:
        """What a snapshot depends on: the press files and the stats of the other files it reads."""
        stats: list[tuple[int, int] | None] = []
        for name in ("manifest.json", "control.json", "control_state.json", WIRE_LOG):
            try:
                st = (self.folder / name).stat()
                stats.append((st.st_size, st.st_mtime_ns))
            except OSError:
                stats.append(None)
        return (tuple(sorted(self._presses.files.items())), *stats)

    def snapshot_json(self) -> bytes:
        """The snapshot as JSON, rebuilt only when a file it reads changed (a finished campaign costs a stat)."""
        self._presses.read(self.folder)
        stamp = self._stamp()
        if stamp != self._cached_stamp:
            self._cached_json = json.dumps(self.snapshot(), allow_nan=False).encode()
            self._cached_stamp = stamp
        return self._cached_json

    def snapshot(self) -> dict[str, Any]:
        folder = self.folder
        try:
            manifest = read_manifest(folder)
            problem = None
        except NeatskinError as exc:
            manifest, problem = {}, str(exc)
        df = self._presses.read(folder)
        counts = manifest.get("counts") or {}
        planned = int(counts.get("planned") or 0)
        pairs = _pairs(df, manifest) if (manifest or not df.empty) else []
        flagged = int(sum(bool(len(f)) for f in df["flags"])) if "flags" in df else 0
        rate, eta = rate_and_eta(df, planned)
        if self._layout is None:
            self._layout = layout_view(folder)
        control = read_state(folder)
        request = read_request(folder)
        lines, position = wire_tail(folder)
        snap: dict[str, Any] = {
            "folder": str(folder),
            "campaign": manifest.get("campaign", folder.name),
            "status": _live_status(folder, manifest),
            "manifest_problem": problem,
            "rig": (manifest.get("rig") or {}).get("kind") if isinstance(manifest.get("rig"), dict) else None,
            "started_at": manifest.get("started_at"),
            "finished_at": manifest.get("finished_at"),
            "control": control,
            "last_request": None if request is None else request.__dict__,
            "counts": {"done": len(df), "planned": planned, "flagged": flagged},
            "rate_per_h": rate,
            "eta_s": eta,
            "since_last_press_s": _since_last_s(df),
            "layout": self._layout,
            "presses": self._press_points(df),
            "last_press": self._last_press(df, manifest, pairs),
            "quality": quality(df, pairs),
            "drift": self._drift(df, pairs),
            "printer": position,
            "wire_tail": wire_text(lines),
            "results": result_links(folder),
            "clock": "UTC",
        }
        return snap

    @staticmethod
    def _press_points(df: pd.DataFrame) -> dict[str, Any]:
        if df.empty:
            return {"press_id": [], "x_mm": [], "y_mm": [], "flag": []}
        kind = []
        for flags in df["flags"]:
            names = {str(f).partition(":")[0] for f in flags}
            kind.append("missed" if "fsr_missed" in names else ("flagged" if names else "ok"))
        return {
            "press_id": df["press_id"].astype(int).tolist(),
            "x_mm": _finite(df["x_mm"]),
            "y_mm": _finite(df["y_mm"]),
            "flag": kind,
        }

    def _last_press(self, df: pd.DataFrame, manifest: dict[str, Any], pairs) -> dict[str, Any] | None:
        if df.empty:
            return None
        row = df.iloc[-1]
        measured = np.array([row[f"dR_ohm_{i}_{j}"] for i, j in pairs], dtype=float)
        expected = self._model.expected_dr_ohm(
            self.folder, manifest, float(row.x_mm), float(row.y_mm), float(row.depth_mm)
        )
        return {
            "press_id": int(row.press_id),
            "x_mm": float(row.x_mm),
            "y_mm": float(row.y_mm),
            "depth_mm": float(row.depth_mm),
            "flags": [str(f) for f in row["flags"]],
            "pairs": [f"{i}-{j}" for i, j in pairs],
            "measured_dr_ohm": _finite(measured),
            "expected_dr_ohm": None if expected is None else _finite(expected),
        }

    @staticmethod
    def _drift(df: pd.DataFrame, pairs) -> dict[str, Any]:
        """Baseline R (R - dR) per pair against press order, relative to each pair's first finite value, in %
        (at most DRIFT_MAX_POINTS presses, evenly strided, the first and last included). A press that cut a pair off
        (R = dR = +inf: no baseline in its row) is a gap (None), as every non-finite value the page gets, and no
        reference: R - dR there would be inf - inf, numpy's 'invalid value encountered in subtract' on every poll."""
        if df.empty:
            return {"press_id": [], "pairs": [], "baseline_pct": [], "baseline_first_ohm": []}
        if len(df) > DRIFT_MAX_POINTS:  # the page draws lines, not every press: an even stride plus the last
            keep = np.unique(np.r_[np.linspace(0, len(df) - 1, DRIFT_MAX_POINTS).astype(int), len(df) - 1])
            df = df.iloc[keep]
        r = df[[f"R_ohm_{i}_{j}" for i, j in pairs]].to_numpy(dtype=float)
        dr = df[[f"dR_ohm_{i}_{j}" for i, j in pairs]].to_numpy(dtype=float)
        cut = ~(np.isfinite(r) & np.isfinite(dr))
        base = np.where(cut, np.nan, r - np.where(cut, 0.0, dr))
        first = np.array([col[np.isfinite(col)][0] if np.isfinite(col).any() else np.nan for col in base.T])
        with np.errstate(invalid="ignore", divide="ignore"):
            pct = 100.0 * (base / first - 1.0)
        return {
            "press_id": df["press_id"].astype(int).tolist(),
            "pairs": [f"{i}-{j}" for i, j in pairs],
            "baseline_pct": [_finite(col) for col in pct.T],
            "baseline_first_ohm": _finite(first),
        }


def _live_status(folder: Path, manifest: dict[str, Any]) -> str:
    """The manifest's status, told apart by the folder lock: a `running` manifest whose process no longer holds
    the lock (killed, SIGKILL included: the kernel drops the flock) is `crashed`; resume finishes it."""
    status = str(manifest.get("status", "unknown"))
    if status == "running" and not lock_state(folder)[0]:
        return "crashed"
    return status

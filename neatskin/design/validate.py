"""Validation of a study's learned error against the full pipeline: for the paper's layout, the study's features-only
estimate beside a small dry-run campaign (simulated printer, DAQ and skin, `ideal` scene) plus the baselines' kNN on
a grouped split, on the same positions, repeats, k, folds and noise level; written into report.md.

What still differs: the dry run's noise comes from the simulated DAQ (white voltage and current noise, 16-bit
quantisation, the RMS demodulation of the protocol), the study's from a Gaussian of the stated per-pair std; the dry
run's presses go through the G-code, the simulated printer and the FSR label (rows it flags are dropped), the study's
are at the commanded (x, y) and depth exactly.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neatskin.baselines.dataset import load_baseline_data
from neatskin.design.candidates import Candidate
from neatskin.design.evaluate import pair_noise
from neatskin.design.learned import learned_error_mm
from neatskin.design.study import LearnedSpec, Study
from neatskin.rig.protocol import load_protocol
from neatskin.rig.runner import run_campaign
from neatskin.skin.model import SkinModel
from neatskin.tomlfile import resolve_path

logger = logging.getLogger(__name__)

SECTION = "## Validation against the full pipeline"
AGREEMENT_SIGMAS = 2.0  # agree when |difference| <= 2 x the combined std over repeats (about a 95 % band)


@dataclass(frozen=True)
class Validation:
    """Both estimates of the kNN grouped mean error (mm) over repeats, and the set-up they share."""

    study_mean_mm: float
    study_std_mm: float
    campaign_mean_mm: float
    campaign_std_mm: float
    campaign_low_mm: float
    campaign_high_mm: float
    positions: int
    repeats: int
    rows: int
    split_repeats: int
    folds: int
    protocol: str
    campaign_folder: str
    own_mean_mm: float  # the study's learned_error_mm itself at this size (its own positions, split and kNN)
    own_std_mm: float
    campaign_noise_ohm: float  # median over pairs of the dry run's feature std about the skin model
    study_noise_ohm: float  # median over pairs of the study's Gaussian std
    paired_max_difference_mm: float  # largest |study - campaign| over the split repeats (the same test rows)

    @property
    def difference_mm(self) -> float:
        return self.study_mean_mm - self.campaign_mean_mm

    @property
    def combined_std_mm(self) -> float:
        return math.hypot(self.study_std_mm, self.campaign_std_mm)

    @property
    def agree(self) -> bool:
        return abs(self.difference_mm) <= AGREEMENT_SIGMAS * self.combined_std_mm


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def _dump_tables(data: dict[str, dict[str, Any]]) -> str:
    """A protocol dict (tables of scalars and lists) as TOML text."""
    lines: list[str] = []
    for table, values in data.items():
        lines.append(f"[{table}]")
        lines += [f"{key} = {_toml_value(v)}" for key, v in values.items()]
        lines.append("")
    return "\n".join(lines)


def validation_protocol(base: str | Path, folder: Path, positions: int, repeats: int) -> Path:
    """A copy of the base protocol with the `ideal` scene, stratified positions, the given counts, features only."""
    path = resolve_path(base)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["files"] = {k: str((path.parent / v).resolve()) for k, v in data.get("files", {}).items()}
    data["campaign"] = {**data.get("campaign", {}), "name": "validation"}
    data["positions"] = {"strategy": "stratified", "count": int(positions)}
    data["press"] = {**data.get("press", {}), "repeats": int(repeats)}
    data["record"] = {"waveforms": False}
    scene = {k: v for k, v in data.get("scene", {}).items() if k in ("fidelity", "noise", "surface_error_mm")}
    data["scene"] = {**scene, "preset": "ideal", "signal": "features", "placement_error_mm": 0.0}
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "validation_protocol.toml"
    out.write_text(_dump_tables(data), encoding="utf-8")
    return out


def study_errors_mm(
    study: Study,
    layout: Any,
    xy_mm: np.ndarray,
    groups: np.ndarray,
    depth_mm: float,
    probe_diameter_mm: float,
    split_repeats: int,
    folds: int,
) -> np.ndarray:
    """The study's features-only estimate at the campaign's positions and rows: one mean error (mm) per split repeat,
    each on a fresh Gaussian noise draw, with the baselines' grouped folds and kNN (k = 5, distance-weighted)."""
    from neatskin.baselines.evaluate import repeat_splits  # scikit-learn, imported when a validation runs
    from neatskin.baselines.models import make_models

    model = SkinModel(layout, fidelity=study.fidelity, probe_radius_mm=probe_diameter_mm / 2.0)
    base = model.baseline_pair_resistance_ohm
    pressed = model.pair_resistance_ohm(xy_mm[:, 0], xy_mm[:, 1], depth_mm)  # (rows, pairs)
    sigma = pair_noise(study).std(base)
    reps, _ = repeat_splits("grouped", groups, split_repeats, 0, folds)
    errors = []
    for rep in reps:
        rng = np.random.default_rng([study.seed, rep.index, 11])
        features = pressed - base + rng.standard_normal(pressed.shape) * sigma
        features = np.where(np.isfinite(features), features, 0.0)
        knn = make_models(["knn"], random_state=0, n_features=features.shape[1], n_rows=len(rep.train))["knn"]
        knn.fit(features[rep.train], xy_mm[rep.train])
        predicted = knn.predict(features[rep.test])
        errors.append(float(np.mean(np.linalg.norm(predicted - xy_mm[rep.test], axis=1))))
    return np.array(errors)


def validate_study(
    study: Study,
    out: str | Path,
    *,
    protocol: str | Path = "protocols/paper.toml",
    positions: int = 40,
    repeats: int = 4,
    split_repeats: int = 5,
    folds: int = 5,
    progress: bool = False,
) -> Validation:
    """Run the dry-run campaign and the baselines' kNN grouped, the study's estimate on the same rows, and write
    the section into out/report.md."""
    from neatskin.baselines.report import run_baselines  # scikit-learn, imported when a validation runs

    out = Path(out)
    folder = out / "validation"
    proto = load_protocol(validation_protocol(protocol, folder, positions, repeats))
    campaign = folder / f"campaign-{positions}x{repeats}"
    if (campaign / "presses.parquet").exists():  # the same seed and protocol give the same campaign: reuse it
        logger.info("reusing the finished dry run in %s", campaign)
    else:
        run_campaign(proto, campaign, dry_run=True, progress=progress, report=False)
    report = run_baselines(
        campaign,
        split="grouped",
        models=["knn"],
        out=folder / "baselines",
        progress=False,
        n_repeats=split_repeats,
        n_splits=folds,
        n_jobs=1,
    )
    row = report.table[(report.table["model"] == "knn") & (report.table["split"] == "grouped")].iloc[0]
    data = load_baseline_data(campaign)
    knn = next(r for r in report.results if r.model == "knn" and r.split == "grouped")
    campaign_errors = np.array([e.mean_error_mm for e in knn.per_repeat])
    study_ = dataclasses.replace(
        study,
        amplitude_a=proto.excitation.amplitude_a,
        live_samples=proto.acquisition.live_samples,
        fidelity=proto.scene.fidelity,
    )
    errors = study_errors_mm(
        study_,
        proto.layout,
        np.asarray(data.y, float),
        np.asarray(data.groups),
        proto.press.press.depth_mm,
        proto.press.press.probe_diameter_mm,
        split_repeats,
        folds,
    )
    xy = np.asarray(data.y, float)
    model = SkinModel(proto.layout, fidelity=study_.fidelity, probe_radius_mm=proto.press.press.probe_diameter_mm / 2)
    base = model.baseline_pair_resistance_ohm
    residual = np.asarray(data.X, float) - (
        model.pair_resistance_ohm(xy[:, 0], xy[:, 1], proto.press.press.depth_mm) - base
    )
    own = _own_estimate(study_, proto, positions, repeats, split_repeats, folds)
    result = Validation(
        study_mean_mm=float(errors.mean()),
        study_std_mm=float(errors.std(ddof=1)) if len(errors) > 1 else 0.0,
        campaign_mean_mm=float(row["mean_error_mm"]),
        campaign_std_mm=float(row["mean_error_mm_std"]),
        campaign_low_mm=float(row["mean_error_mm_lo"]),
        campaign_high_mm=float(row["mean_error_mm_hi"]),
        positions=len(np.unique(data.groups)),
        repeats=int(repeats),
        rows=len(data.y),
        split_repeats=int(split_repeats),
        folds=int(folds),
        protocol=str(resolve_path(protocol)),
        campaign_folder=str(campaign),
        own_mean_mm=float(own.mean()),
        own_std_mm=float(own.std(ddof=1)) if len(own) > 1 else 0.0,
        campaign_noise_ohm=float(np.median(residual.std(axis=0, ddof=1))),
        study_noise_ohm=float(np.median(pair_noise(study_).std(base))),
        paired_max_difference_mm=float(np.max(np.abs(errors - campaign_errors))),
    )
    write_section(out / "report.md", validation_markdown(result, study_))
    logger.info("validation: study %.3g mm, campaign %.3g mm", result.study_mean_mm, result.campaign_mean_mm)
    return result


def _own_estimate(study: Study, proto: Any, positions: int, repeats: int, split_repeats: int, folds: int) -> np.ndarray:
    """The study's learned_error_mm as it runs in a study, at the same size and held-out share: uniform positions
    over the layout, one group-shuffle split per seed, k = 5 uniform weights."""
    spec = LearnedSpec(True, positions, repeats, split_repeats, 1.0 / folds, "knn")
    press = proto.press.press
    candidate = Candidate(3, 3, 15.0, 2.0, 1.0, press.probe_diameter_mm, press.depth_mm, "explicit", 8, "paper", ())
    study = dataclasses.replace(study, learned=spec)
    return learned_error_mm(proto.layout, study, candidate, pair_noise(study))


def validation_markdown(v: Validation, study: Study) -> str:
    """The report section: both estimates with their spreads, the verdict and what still differs."""
    verdict = "agree" if v.agree else "do NOT agree"
    return "\n".join(
        [
            SECTION,
            "",
            f"The paper's layout (`{Path(v.protocol).name}`, `ideal` scene), {v.positions} stratified positions x "
            f"{v.repeats} repeats ({v.rows} presses kept), kNN (k = 5, distance-weighted, standardised features), "
            f"grouped {v.folds}-fold split by position, {v.split_repeats} split repeats; mean Euclidean test error, "
            "mean +- std over split repeats.",
            "",
            "| estimate | mean error (mm) | std over repeats (mm) |",
            "|---|---|---|",
            f"| study: features-only simulation (skin model + Gaussian noise) | {v.study_mean_mm:.4f} | "
            f"{v.study_std_mm:.3f} |",
            f"| full pipeline: dry-run campaign + `neatskin baselines` (95 % interval of the mean "
            f"{v.campaign_low_mm:.3f} to {v.campaign_high_mm:.3f}) | {v.campaign_mean_mm:.4f} | "
            f"{v.campaign_std_mm:.3f} |",
            f"| study's `learned` as a study runs it (uniform positions, k = 5 uniform weights, held-out share "
            f"{1 / v.folds:.2g}, {v.split_repeats} seeds) | {v.own_mean_mm:.3f} | {v.own_std_mm:.3f} |",
            "",
            f"Noise per pair (median over pairs): the dry run's features scatter {v.campaign_noise_ohm:.3g} ohm about "
            f"the skin model; the study's Gaussian has std {v.study_noise_ohm:.3g} ohm. At this size the error is "
            "set by interpolating between training positions, not by the noise, so the first two rows can agree far "
            "closer than their spread.",
            "",
            f"Difference {v.difference_mm:+.4f} mm against a combined std of {v.combined_std_mm:.3f} mm: the two "
            f"{verdict} within {AGREEMENT_SIGMAS:g} combined std. Both use the same test rows in each split repeat, "
            "so their spreads are correlated (most of the std is which positions are held out); the sharper check is "
            f"the paired one: the largest per-repeat difference is {v.paired_max_difference_mm:.4f} mm.",
            "",
            "Made the same: the positions and press rows (the study's estimate is computed at the campaign's recorded "
            "positions and its kept rows), repeats, k, folds, split seeds, the protocol's excitation "
            f"({1e3 * study.amplitude_a:g} mA) and live samples ({study.live_samples}). What still differs: the dry "
            "run's noise comes from the simulated DAQ (white voltage and current noise, 16-bit quantisation, the "
            "protocol's demodulation), the study's from a Gaussian of the stated per-pair std "
            f"(`{study.noise_model}` model); the dry run's presses pass the G-code, the simulated printer and the FSR "
            "label, the study's are at the commanded (x, y) and depth exactly; each study repeat draws fresh noise.",
            f"Campaign folder: `{v.campaign_folder}`.",
            "",
        ]
    )


_SECTION_RE = re.compile(re.escape(SECTION) + r".*?(?=^## |\Z)", re.S | re.M)


def existing_section(report: Path) -> str | None:
    """The validation section of report.md as written, or None (no report, or no section in it)."""
    text = report.read_text(encoding="utf-8") if report.exists() else ""
    found = _SECTION_RE.search(text)
    return found.group(0) if found else None


def write_section(report: Path, section: str) -> None:
    """Put the section into report.md, replacing an earlier one (up to the next `## ` heading)."""
    text = report.read_text(encoding="utf-8") if report.exists() else ""
    if _SECTION_RE.search(text):
        text = _SECTION_RE.sub(lambda _: section, text)
    else:
        text = (text.rstrip("\n") + "\n\n" if text else "") + section
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(text, encoding="utf-8")

"""Validation of a design study that can fail: the study's predictions against simulated campaigns (`rig.simcampaign`,
the dry run's skin and scene engine) whose positions, folds, seeds and model are not the study's; a negative control
with the campaigns' skin pinch changed, and the power of the check.

Candidates: the study's candidates with fixed placements (at least 3), and its optimised placements when a run of
this study produced them in OUT (`validateset.py`; else one line says they are left out and how to make them).
Per candidate, three checks:
- level: the study's learned error (its uniform positions, group-shuffle split, k = 5 uniform kNN, its seeds)
  against campaigns in the scene the study assumes (no placement error, jitter, drift or fabrication; the study's
  Gaussian noise; the study's parametric pinch) but with the dry run's skin, the protocol's position strategy, 5-fold grouped splits, the
  baselines' distance-weighted kNN and other seeds; agree within 2 combined standard errors + LEVEL_TOLERANCE;
- transfer: a kNN trained on the study's own simulated dataset, scored on those campaigns, against the campaigns'
  own kNN: the study's physics predicts the campaign's presses when the two are within 2 standard errors +
  TRANSFER_TOLERANCE of the campaign's error. This is the check with power against wrong physics (the learned
  error alone barely moves with the pinch: interpolation between training positions sets it);
- ranking (over candidates): campaigns in the protocol's own scene (paper-like: the finite-element pinch kernel,
  placement, jitter, drift, fabrication, displaced fluid) order the candidates' errors as the study does, for every pair the study separates;
  beside it, optimised against boundary at each electrode count (paired over seeds: the same positions and splits).
The verdict agrees when every check agrees. The pinch of the campaigns' skin can be scaled (`pinch_scale`): the
negative control uses 0.6 (a 40 % change) and must disagree; the power sweep reports the smallest change detected.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neatskin.design.study import Study
from neatskin.design.validateset import fixed_candidates, validation_set

SECTION = "## Validation against simulated campaigns"
CAMPAIGN_SEEDS = 5
SEED_BASE = 7001  # campaign seeds 7001.. : never a study's
FOLDS = 5
LEVEL_TOLERANCE = 0.10  # share of the campaign's error allowed beside the seeds' spread (positions' strategy differs)
TRANSFER_TOLERANCE = 0.15  # share: a study-trained model may lose this much on campaign presses
NEGATIVE_PINCH = 0.6
POWER_SCALES = (0.95, 1.05, 0.9, 1.1, 0.8, 1.2, 0.7, 1.3)


@dataclass(frozen=True)
class CandidateCheck:
    """One candidate's numbers (mm): study, campaigns as the study assumes, transfer, campaigns in the protocol's scene."""

    label: str
    study_mm: np.ndarray
    campaign_mm: np.ndarray
    transfer_mm: np.ndarray
    scene_mm: np.ndarray
    skin: tuple[float, ...] = ()  # validateset.skin_key: placements compete only on the same skin
    strategy: str = ""
    count: int = 0

    @staticmethod
    def _se(values: np.ndarray) -> float:
        return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0

    @property
    def level_agrees(self) -> bool:
        band = 2 * np.hypot(self._se(self.study_mm), self._se(self.campaign_mm))
        return abs(self.study_mm.mean() - self.campaign_mm.mean()) <= band + LEVEL_TOLERANCE * self.campaign_mm.mean()

    @property
    def transfer_gap_mm(self) -> float:
        return float(np.mean(self.transfer_mm - self.campaign_mm))

    @property
    def transfer_agrees(self) -> bool:
        band = 2 * self._se(self.transfer_mm - self.campaign_mm)
        return self.transfer_gap_mm <= band + TRANSFER_TOLERANCE * float(self.campaign_mm.mean())


@dataclass(frozen=True)
class Validation:
    checks: tuple[CandidateCheck, ...]
    pinch_scale: float
    ranking_agrees: bool
    kendall_tau: float
    power: tuple[tuple[float, bool], ...] = ()
    note: str | None = None  # the optimised candidates left out, and why

    @property
    def head_to_head(self) -> list[HeadToHead]:
        """Optimised against boundary at the same count on the same skin, for every optimised candidate checked."""
        boundary = {(c.skin, c.count): c for c in self.checks if c.strategy == "boundary"}
        return [
            HeadToHead(c, boundary[(c.skin, c.count)])
            for c in self.checks
            if c.strategy == "optimised" and (c.skin, c.count) in boundary
        ]

    @property
    def agree(self) -> bool:
        return self.ranking_agrees and all(c.level_agrees and c.transfer_agrees for c in self.checks)

    @property
    def smallest_detected(self) -> float | None:
        found = [abs(s - 1) for s, detected in self.power if detected]
        return min(found) if found else None


@dataclass(frozen=True)
class HeadToHead:
    """Optimised against boundary with the same electrodes on the same skin. Both sides use the same seeds (the
    study: the same positions, noise shape and split per seed; the campaigns: the same positions per seed), so the
    difference is taken per seed: mean and standard error of (optimised - boundary)."""

    optimised: CandidateCheck
    boundary: CandidateCheck

    @staticmethod
    def _paired(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
        d = a - b
        return float(d.mean()), CandidateCheck._se(d)

    @property
    def study_diff_mm(self) -> tuple[float, float]:
        return self._paired(self.optimised.study_mm, self.boundary.study_mm)

    @property
    def scene_diff_mm(self) -> tuple[float, float]:
        return self._paired(self.optimised.scene_mm, self.boundary.scene_mm)

    @property
    def order(self) -> str:
        """'same order' or 'reversed' (the signs of the two differences), with whether each side separates them
        beyond 2 of its paired standard errors."""
        (ds, ss), (dc, sc) = self.study_diff_mm, self.scene_diff_mm
        same = "same order" if ds * dc > 0 else "reversed" if ds * dc < 0 else "tied"
        sep = [name for name, d, se in (("study", ds, ss), ("campaigns", dc, sc)) if abs(d) > 2 * se]
        return f"{same}; separated beyond 2 paired SE by: {', '.join(sep) or 'neither'}"


def validation_candidates(study: Study) -> list[Any]:
    """The study's fixed placements (at least 3; ConfigError otherwise)."""
    return fixed_candidates(study)


def _campaign_protocol(base, study: Study, candidate, layout, ideal: bool):
    scene = dataclasses.replace(base.scene, fidelity=study.fidelity)
    if ideal:
        scene = dataclasses.replace(
            scene,
            placement_error_mm=0.0,
            depth_jitter_mm=0.0,
            temperature_drift_k_per_h=0.0,
            evaporation_fraction_per_h=0.0,
            fabrication_spread_fraction=0.0,
            displaced_fluid_fraction=0.0,
            deformation="parametric",  # the study's own pinch; the protocol's scene presses the FE kernel
        )
    press = dataclasses.replace(
        base.press,
        positions=dataclasses.replace(base.press.positions, count=study.learned.positions),
        press=dataclasses.replace(
            base.press.press,
            repeats=study.learned.repeats,
            depth_mm=candidate.depth_mm,
            probe_diameter_mm=candidate.probe_diameter_mm,
        ),
    )
    return dataclasses.replace(base, layout=layout, press=press, scene=scene, skin_profile=None)


def _knn_error(features, targets, groups) -> float:
    from sklearn.model_selection import GroupKFold

    from neatskin.baselines.models import make_models

    errors = []
    for train, test in GroupKFold(FOLDS).split(features, groups=groups):
        knn = make_models(["knn"], random_state=0, n_features=features.shape[1], n_rows=len(train))["knn"]
        knn.fit(features[train], targets[train])
        errors.append(np.linalg.norm(knn.predict(features[test]) - targets[test], axis=1))
    return float(np.mean(np.concatenate(errors)))


@dataclass(frozen=True)
class StudySide:
    """What a candidate's checks take from the study, whatever pinch the campaigns press: its layout, the study's
    learned error over its seeds, a kNN trained on its own simulated dataset and the pair noise's std. Built once
    per candidate (`study_side`) and shared by the power sweep's scales."""

    layout: Any
    study_mm: np.ndarray
    trained: Any
    sigma: np.ndarray


def study_side(study: Study, candidate) -> StudySide:
    from neatskin.baselines.models import make_models
    from neatskin.design.evaluate import candidate_layout, canonical_nodes, pair_noise
    from neatskin.design.learned import learned_error_mm, simulated_features
    from neatskin.skin.model import SkinModel

    # the study's own electrode order (evaluate_candidate's): the same pairs in the same order draw the same noise,
    # so the study column is the study's learned error itself (the boundary walk's order gave 4.90 for its 4.88 mm)
    layout = candidate_layout(study, candidate, canonical_nodes(candidate.nodes))
    noise = pair_noise(study)
    study_mm = learned_error_mm(layout, study, candidate, noise)
    features, targets, _ = simulated_features(layout, study, candidate, noise, 0)
    trained = make_models(["knn"], random_state=0, n_features=features.shape[1], n_rows=len(features))["knn"]
    trained.fit(features, targets)
    sigma = noise.std(SkinModel(layout, fidelity=study.fidelity).baseline_pair_resistance_ohm)
    return StudySide(layout, study_mm, trained, sigma)


def check_candidate(
    study: Study,
    base_protocol,
    candidate,
    pinch_scale: float = 1.0,
    seeds: int = CAMPAIGN_SEEDS,
    side: StudySide | None = None,
    protocol_scene: bool = True,
):
    """The numbers of one candidate (a picklable unit of work for joblib). `side`: the study's side when already
    built; `protocol_scene=False` skips the campaigns in the protocol's scene (the ranking's, which the power
    sweep does not read: its scene_mm is then empty)."""
    from neatskin.rig.simcampaign import simulate_presses, skin_of, strategy_positions

    side = study_side(study, candidate) if side is None else side
    campaign: list[float] = []
    transfer: list[float] = []
    scene: list[float] = []
    runs = ((True, campaign), (False, scene)) if protocol_scene else ((True, campaign),)
    for ideal, out in runs:
        proto = _campaign_protocol(base_protocol, study, candidate, side.layout, ideal)
        skin = skin_of(proto, pinch_scale)
        for k in range(seeds):
            seed = SEED_BASE + k
            xy = strategy_positions(proto, study.learned.positions, seed)
            presses = simulate_presses(
                proto,
                xy,
                study.learned.repeats,
                candidate.depth_mm,
                seed,
                side.sigma,
                skin=skin,
                interval_s=float(proto.scene.press_interval_s or 7.78),
            )
            out.append(_knn_error(presses.features, presses.commanded_mm, presses.groups))
            if ideal:
                predicted = side.trained.predict(presses.features)
                transfer.append(float(np.mean(np.linalg.norm(predicted - presses.commanded_mm, axis=1))))
    from neatskin.design.validateset import label, skin_key

    return CandidateCheck(
        label(candidate),
        side.study_mm,
        np.array(campaign),
        np.array(transfer),
        np.array(scene),
        skin_key(candidate),
        candidate.strategy,
        candidate.count,
    )


def ranking(checks: list[CandidateCheck]) -> tuple[bool, float]:
    """(agrees, Kendall tau): no pair the study separates (beyond 2 combined SE) is ordered the other way by the
    campaigns in the protocol's scene beyond their own 2 SE."""
    from scipy.stats import kendalltau

    agrees = True
    for a, b in itertools.combinations(checks, 2):
        d_study = a.study_mm.mean() - b.study_mm.mean()
        d_scene = a.scene_mm.mean() - b.scene_mm.mean()
        se_study = np.hypot(CandidateCheck._se(a.study_mm), CandidateCheck._se(b.study_mm))
        se_scene = np.hypot(CandidateCheck._se(a.scene_mm), CandidateCheck._se(b.scene_mm))
        if abs(d_study) > 2 * se_study and d_study * d_scene < 0 and abs(d_scene) > 2 * se_scene:
            agrees = False
    tau = kendalltau([c.study_mm.mean() for c in checks], [c.scene_mm.mean() for c in checks]).statistic
    return agrees, float(tau)


def validate_study(
    study: Study,
    protocol: str | Path = "protocols/paper.toml",
    *,
    pinch_scale: float = 1.0,
    power: bool = True,
    n_jobs: int = 2,
    progress: Callable[[int, int], None] | None = None,
    out: str | Path | None = None,
) -> Validation:
    """The checks for every fixed candidate, with campaigns whose pinch is scaled by `pinch_scale`; with `power`,
    the transfer check again with the study's pinch scaled by each of POWER_SCALES (the smallest change it detects;
    the same whatever `pinch_scale` is). `out`: the study's folder, whose run's optimised placements are checked
    too (validateset.py; without it or without that run they are left out, with a note). `progress(done, total)` is called as each step ends: a candidate's check,
    the power sweep's study side, each scale of the sweep (the CLI draws it as a bar)."""
    from joblib import delayed

    from neatskin.orphans import watched_parallel
    from neatskin.rig.protocol import load_protocol
    from neatskin.tomlfile import resolve_path

    base = load_protocol(resolve_path(protocol))
    chosen = validation_set(study, None if out is None else Path(out))
    candidates = list(chosen.candidates)
    total = len(candidates) + (1 + len(POWER_SCALES) if power else 0)
    done = 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    def counted(results: Iterable[CandidateCheck]) -> list[CandidateCheck]:
        """The results in order (joblib's ordered generator), a step each as it arrives."""
        out = []
        for result in results:
            out.append(result)
            step()
        return out

    if progress is not None:
        progress(0, total)
    checks = counted(
        watched_parallel(n_jobs, return_as="generator")(
            delayed(check_candidate)(study, base, c, pinch_scale) for c in candidates
        )
    )
    agrees, tau = ranking(checks)
    found: list[tuple[float, bool]] = []
    if power:
        probe = candidates[0]
        side = study_side(study, probe)  # the study's side does not depend on the scale: built once, not per scale
        step()
        scaled = counted(
            watched_parallel(n_jobs, return_as="generator")(
                # the study's own pinch scaled, whatever `pinch_scale` the run's campaigns press: power is the
                # check's, and scaling a negative control's already weakened pinch called every change detected
                delayed(check_candidate)(study, base, probe, s, 3, side, protocol_scene=False)
                for s in POWER_SCALES
            )
        )
        found = [(s, not (c.transfer_agrees and c.level_agrees)) for s, c in zip(POWER_SCALES, scaled, strict=True)]
    return Validation(tuple(checks), pinch_scale, agrees, tau, tuple(found), chosen.note)


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

"""A learned localisation error for a candidate: a simulated features-only dataset (the skin model's pressed pair
resistances plus Gaussian noise of the study's per-pair std, not the whole campaign machinery), split by position
(no repeat of a test position is trained on), one regressor, the mean Euclidean test error per seed.

Positions are uniform over the layout's bounds; every repeat of a position is pressed at the same (x, y) and
depth (no placement or depth error: the same ideal scene as the bound). Each seed draws a new dataset and split.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from neatskin.design.bound import PairNoise
from neatskin.design.candidates import Candidate
from neatskin.design.study import Study
from neatskin.layout import Layout
from neatskin.skin.model import SkinModel


def simulated_features(
    layout: Layout, study: Study, candidate: Candidate, noise: PairNoise, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (presses, pairs) dR in ohm, targets (presses, 2) in mm, groups (presses,) position ids)."""
    spec = study.learned
    rng = np.random.default_rng([study.seed, seed, 7])
    x0, y0, x1, y1 = layout.bounds_mm
    xy = rng.uniform((x0, y0), (x1, y1), size=(spec.positions, 2))
    model = SkinModel(layout, fidelity=study.fidelity, probe_radius_mm=candidate.probe_diameter_mm / 2.0)
    base = model.baseline_pair_resistance_ohm
    pressed = model.pair_resistance_ohm(xy[:, 0], xy[:, 1], candidate.depth_mm)  # (positions, pairs)
    sigma = noise.std(base)
    features = np.repeat(pressed - base, spec.repeats, axis=0)
    features = features + rng.standard_normal(features.shape) * sigma
    features = np.where(np.isfinite(features), features, 0.0)  # a pair cut apart reads as no change
    targets = np.repeat(xy, spec.repeats, axis=0)
    groups = np.repeat(np.arange(spec.positions), spec.repeats)
    return features, targets, groups


def learned_error_mm(
    layout: Layout, study: Study, candidate: Candidate, noise: PairNoise, tick: Callable[[int], None] | None = None
) -> np.ndarray:
    """Mean Euclidean test error (mm) of the study's regressor, one value per seed, (seeds,); tick(press
    evaluations) after each seed (the progress bar)."""
    from sklearn.ensemble import ExtraTreesRegressor
    from sklearn.model_selection import GroupShuffleSplit
    from sklearn.neighbors import KNeighborsRegressor
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    spec = study.learned
    errors = []
    for seed in range(spec.seeds):
        features, targets, groups = simulated_features(layout, study, candidate, noise, seed)
        split = GroupShuffleSplit(n_splits=1, test_size=spec.test_share, random_state=int(study.seed * 1000 + seed))
        train, test = next(split.split(features, targets, groups))
        if spec.model == "knn":
            regressor = make_pipeline(StandardScaler(), KNeighborsRegressor(n_neighbors=5))
        else:
            regressor = ExtraTreesRegressor(n_estimators=100, random_state=seed, n_jobs=1)
        regressor.fit(features[train], targets[train])
        predicted = regressor.predict(features[test])
        errors.append(float(np.mean(np.linalg.norm(predicted - targets[test], axis=1))))
        if tick is not None:
            tick(spec.positions * layout.n_electrodes)
    return np.array(errors)

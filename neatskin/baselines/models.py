"""The baseline zoo: every model the report compares, as scikit-learn estimators or pipelines.

Each input-scale-sensitive model standardises its features (a dead electrode's constant
column maps to 0, features 1e6 apart in scale become comparable) and, where the model
shrinks towards zero, its targets too. The paper's LM network scales both to [0, 1] itself.
"""

from __future__ import annotations

from collections.abc import Iterable

from sklearn.base import BaseEstimator
from sklearn.compose import TransformedTargetRegressor
from sklearn.ensemble import ExtraTreesRegressor
from sklearn.kernel_ridge import KernelRidge
from sklearn.linear_model import RidgeCV
from sklearn.neighbors import KNeighborsRegressor
from sklearn.neural_network import MLPRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from neatskin.baselines.lm import LMNetworkRegressor
from neatskin.errors import DataError

MODEL_NAMES = ("ridge", "knn", "kernel_ridge", "extra_trees", "mlp", "lm_network")
PHYSICS_MODELS = ("inversion",)  # no training: see neatskin.baselines.inversion
SMALL_ROWS = 500  # below this many training rows the costly models get small defaults

# Seconds per fit on the paper dry run's ~2,700 training rows (one core, load ~1-3: rough), and how a fit's
# cost grows with the rows (exponent). Used for nothing but running the costliest tasks first.
_FIT_COST_S = {"ridge": 0.005, "knn": 0.003, "kernel_ridge": 0.7, "extra_trees": 0.6, "mlp": 1.2, "lm_network": 0.5}
_COST_EXPONENT = {"kernel_ridge": 2.0}
_COST_ROWS = 2700
INVERSION_COST_S_PER_PRESS = 0.7e-3  # the physics inversion, per press (all presses in one task; the solver before
# issue 27 was 5.4x slower on a paper dry run, the analytic Jacobian's 2.25 s for 2,800 presses at load 5: rough,
# benchmarks/bench_inversion.py)

# Above these many training rows a model trains on an even draw over the positions (`even_draw`), so a
# merged dataset of 100 campaigns (280,000 presses) stays within memory and minutes: kernel ridge's kernel
# matrix is rows^2 x 8 bytes (5,000 rows: 200 MB; 224,000: 400 GB), the trees' nodes, the LM's Jacobian
# and the neighbours' distances grow with the rows. Chosen (assumed, not fitted) as 2x to 9x the paper's
# 2,240 training rows, so the paper's campaign and anything up to a few merged campaigns is never capped.
# Ridge uses every row.
TRAIN_ROW_CAP = {"kernel_ridge": 5_000, "extra_trees": 20_000, "mlp": 20_000, "lm_network": 20_000, "knn": 20_000}
INVERSION_MAX_PRESSES = 20_000  # above this the physics inversion (~1 ms a press) runs only when named

DESCRIPTIONS = {
    "ridge": "linear: standardised features, ridge with alpha by leave-one-out CV",
    "knn": "5 nearest neighbours (distance-weighted) on standardised features",
    "kernel_ridge": "kernel ridge, RBF kernel (gamma = 1 / (2 n_features)), standardised features and targets",
    "extra_trees": "extremely randomised trees, 50 trees",
    "mlp": "MLPRegressor 64-64 ReLU, adam until the training loss stalls, standardised features and targets",
    "lm_network": "the paper's n-5-2 tanh network, Levenberg-Marquardt, stopped early on a validation share of its "
    "training rows (3 of the 98 % that are not test: the paper's 95/3/2 split; whole held-out positions on the grouped "
    "split); with several restarts, the one best on validation",
    "inversion": "physics, no training: per press (x, y, depth) by least squares through the skin's forward model "
    "(SkinModel of the campaign's layout), from a 1 mm grid start",
}


def _scaled_target(regressor: BaseEstimator) -> TransformedTargetRegressor:
    return TransformedTargetRegressor(regressor=regressor, transformer=StandardScaler())


def make_model(
    name: str,
    random_state: int | None = 0,
    n_features: int = 28,
    n_rows: int | None = None,
    lm_restarts: int | None = None,
) -> BaseEstimator:
    """One fresh, unfitted baseline by name (see MODEL_NAMES).

    n_rows: training rows; below SMALL_ROWS the MLP and the LM restarts get small defaults (32-32,
    3 restarts): on a few hundred presses more buys nothing measurable.
    lm_restarts: the LM network's restarts (default 10, or 3 on small data).
    """
    small = n_rows is not None and n_rows < SMALL_ROWS
    if name == "ridge":
        return make_pipeline(StandardScaler(), RidgeCV(alphas=(1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)))
    if name == "knn":
        return make_pipeline(StandardScaler(), KNeighborsRegressor(n_neighbors=5, weights="distance"))
    if name == "kernel_ridge":
        kernel = KernelRidge(kernel="rbf", alpha=1e-2, gamma=1.0 / (2.0 * max(n_features, 1)))
        return make_pipeline(StandardScaler(), _scaled_target(kernel))
    if name == "extra_trees":
        # 50 trees: on the paper dry run (10 repeats, same splits) 100 trees were 0.009 mm better in mean error on
        # both the grouped (2.236 -> 2.227 mm) and the random split (1.512 -> 1.503 mm), against a spread over
        # repeats of 0.15 mm, for twice the time (a sixth of the report's fit time); 25 trees lose 0.02 mm
        return ExtraTreesRegressor(n_estimators=50, min_samples_leaf=2, random_state=random_state, n_jobs=1)
    if name == "mlp":
        # no early stopping: its internal validation split fails on a handful of presses
        width = 32 if small else 64
        mlp = MLPRegressor(hidden_layer_sizes=(width, width), max_iter=1000, alpha=1e-3, random_state=random_state)
        return make_pipeline(StandardScaler(), _scaled_target(mlp))
    if name == "lm_network":
        restarts = lm_restarts if lm_restarts is not None else (3 if small else 10)
        return LMNetworkRegressor(n_hidden=5, n_restarts=restarts, val_fraction=3 / 98, random_state=random_state)
    raise DataError(f"unknown model {name!r}", field="models", fix=f"choose from {', '.join(MODEL_NAMES)}")


def fit_cost_s(name: str, n_rows: int) -> float:
    """Rough seconds for one fit of model `name` on n_rows training rows (only to order tasks)."""
    scale = max(n_rows, 1) / _COST_ROWS
    return _FIT_COST_S.get(name, 1.0) * scale ** _COST_EXPONENT.get(name, 1.0)


def make_models(
    names: Iterable[str] | None = None,
    random_state: int | None = 0,
    n_features: int = 28,
    n_rows: int | None = None,
    lm_restarts: int | None = None,
) -> dict[str, BaseEstimator]:
    """Fresh baselines keyed by name, in MODEL_NAMES order when names is None."""
    chosen = MODEL_NAMES if names is None else tuple(names)
    return {name: make_model(name, random_state, n_features, n_rows, lm_restarts) for name in chosen}

"""The inversion's surrogate: a skin model's dR(x, y, depth) for every pair, tabulated once on a uniform grid and
interpolated by a tensor-product cubic B-spline (exact at the nodes, C2, with exact value, gradient and Hessian of
the interpolant), and its on-disk cache per skin model (docs/baselines.md, issue 27's seventh round).

Not the default path of the inversion (`skin_inversion(..., method="surrogate")`, `invpolish`): the measurements are in
docs/baselines.md.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np

from neatskin.baselines.invsolve import BIG_OHM, GRADIENT_CHUNK, model_dr

logger = logging.getLogger(__name__)

TABLE_FORMAT = 1  # bump when the table's content for the same skin and grid changes (the cache key holds it)
EVAL_CHUNK = 2048  # rows per gather: (rows, 64, pairs) float64 stays ~30 MB


def _axis_solver(n: int) -> np.ndarray:
    """(n + 2, n) matrix taking n node values on a uniform axis to the n + 2 cubic B-spline coefficients of their
    not-a-knot interpolant (the third derivative continuous at the second and the last-but-one node)."""
    if n < 4:
        raise ValueError(f"a cubic table axis needs at least 4 nodes, got {n}")
    a = np.zeros((n + 2, n + 2))
    for i in range(n):
        a[i, i : i + 3] = (1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0)
    a[n, 0:5] = (1.0, -4.0, 6.0, -4.0, 1.0)
    a[n + 1, n - 3 : n + 2] = (1.0, -4.0, 6.0, -4.0, 1.0)
    return np.linalg.inv(a)[:, :n]


def _basis(u: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell index (m,) and the 4 uniform cubic B-spline weights with their first and second derivatives in the
    node coordinate u, (m, 3, 4); u outside [0, n - 1] extends the end cells' cubics."""
    cell = np.clip(np.floor(u), 0, n - 2).astype(np.int64)
    t = u - cell
    t2, t3, s = t * t, t * t * t, 1.0 - t
    w = np.empty((len(u), 3, 4))
    w[:, 0, 0] = s * s * s / 6.0
    w[:, 0, 1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
    w[:, 0, 2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
    w[:, 0, 3] = t3 / 6.0
    w[:, 1, 0] = -0.5 * s * s
    w[:, 1, 1] = 1.5 * t2 - 2.0 * t
    w[:, 1, 2] = -1.5 * t2 + t + 0.5
    w[:, 1, 3] = 0.5 * t2
    w[:, 2, 0] = s
    w[:, 2, 1] = 3.0 * t - 2.0
    w[:, 2, 2] = 1.0 - 3.0 * t
    w[:, 2, 3] = t
    return cell, w


# the (x, y, depth) derivative orders of the value, the gradient and the Hessian's upper triangle
ORDERS = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (2, 0, 0), (1, 1, 0), (1, 0, 1), (0, 2, 0), (0, 1, 1), (0, 0, 2))
_HESSIAN = ((4, 5, 6), (5, 7, 8), (6, 8, 9))
_ORDER_INDEX = np.array(ORDERS).T  # (3 axes, 10)  # ORDERS index of d2/da db


@dataclass(frozen=True)
class SplineTable:
    """dR (ohm) of every pair on a uniform (x, y, depth) grid as cubic B-spline coefficients.

    lo, step: the grid's first node and spacing per axis (mm); shape: nodes per axis; coef: (nx + 2, ny + 2,
    nd + 2, pairs) float64, C order (a node's 4 depth coefficients are contiguous: one gather of 4 x pairs)."""

    lo: tuple[float, float, float]
    step: tuple[float, float, float]
    shape: tuple[int, int, int]
    values: np.ndarray  # (nx, ny, nd, pairs) the model's dR at the nodes
    coef: np.ndarray

    @classmethod
    def from_values(cls, lo, step, values: np.ndarray) -> SplineTable:
        """The interpolant of node values (nx, ny, nd, pairs)."""
        values = np.ascontiguousarray(values, dtype=float)
        coef = values
        for axis in range(3):
            coef = np.moveaxis(np.tensordot(_axis_solver(values.shape[axis]), coef, axes=(1, axis)), 0, axis)
        shape = (int(values.shape[0]), int(values.shape[1]), int(values.shape[2]))
        return cls(
            (float(lo[0]), float(lo[1]), float(lo[2])),
            (float(step[0]), float(step[1]), float(step[2])),
            shape,
            values,
            np.ascontiguousarray(coef),
        )

    def node_index(self, p: np.ndarray) -> np.ndarray | None:
        """Flat node indices (m,) if every row of p is a node of the grid (to 1e-9 of a step), else None."""
        u = (np.asarray(p, float) - np.array(self.lo)) / np.array(self.step)
        k = np.rint(u)
        if not (np.all(np.abs(u - k) < 1e-9) and np.all(k >= 0) and np.all(k < np.array(self.shape))):
            return None
        k = k.astype(np.int64)
        return (k[:, 0] * self.shape[1] + k[:, 1]) * self.shape[2] + k[:, 2]

    def nodes(self) -> np.ndarray:
        """The grid's nodes (nx, ny, nd, 3)."""
        axes = [self.lo[a] + self.step[a] * np.arange(self.shape[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def evaluate(self, p: np.ndarray, order: int = 2) -> np.ndarray:
        """(m, k, pairs) at rows p (m, 3): k = 1 the value, 4 with the gradient, 10 with the Hessian (ORDERS)."""
        k = {0: 1, 1: 4, 2: 10}[order]
        out = np.empty((len(p), k, self.coef.shape[-1]))
        for start in range(0, len(p), EVAL_CHUNK):
            out[start : start + EVAL_CHUNK] = self._evaluate(np.asarray(p[start : start + EVAL_CHUNK], float), k)
        return out

    def _evaluate(self, p: np.ndarray, k: int) -> np.ndarray:
        m, pairs = len(p), self.coef.shape[-1]
        nx, ny, nd = self.coef.shape[:3]
        cells, weights = [], []
        for a in range(3):
            cell, w = _basis((p[:, a] - self.lo[a]) / self.step[a], self.shape[a])
            cells.append(cell)
            weights.append(w / np.array([1.0, self.step[a], self.step[a] ** 2])[None, :, None])
        # every (x, y) node's 4 depth coefficients are one contiguous run of 4 x pairs floats: 16 gathers a row
        flat = self.coef.reshape(-1, pairs)
        runs = np.lib.stride_tricks.as_strided(
            flat, shape=(len(flat) - 3, 4 * pairs), strides=(flat.strides[0], flat.strides[1]), writeable=False
        )
        four = np.arange(4)
        first = (cells[0][:, None, None] + four[None, :, None]) * ny + cells[1][:, None, None] + four[None, None, :]
        # indexing, not np.take: take copies a strided (overlapping) source whole first (~4x the table a call)
        gathered = runs[(first * nd + cells[2][:, None, None]).reshape(m, 16)].reshape(m, 64, pairs)
        wx, wy, wd = weights
        orders = _ORDER_INDEX[:, :k]
        combos = wx[:, orders[0], :, None, None] * wy[:, orders[1], None, :, None]
        combos = combos * wd[:, orders[2], None, None, :]
        return np.matmul(combos.reshape(m, k, 64), gathered)


def hessian(values: np.ndarray) -> np.ndarray:
    """(m, pairs, 3, 3) from `SplineTable.evaluate(..., order=2)`'s (m, 10, pairs)."""
    return np.moveaxis(values[:, np.array(_HESSIAN)], -1, 1)


class TableSkin:
    """A skin model's stand-in for the inversion: `pair_resistance_ohm` and its derivatives from a `SplineTable`
    (the baseline, the unpressed resistances, added back; a row at depth <= 0 is unpressed: dR 0). Rows on the
    table's nodes take the tabulated values (the grids of the start search: no interpolation)."""

    has_analytic_jacobian = True

    def __init__(self, table: SplineTable, baseline_ohm: np.ndarray):
        self.table = table
        self.baseline_ohm = np.asarray(baseline_ohm, float)
        self.rows = 0  # rows evaluated (a value with its gradient and Hessian counts one)

    def pair_resistance_ohm(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        p = np.stack(np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm))), -1)
        out = np.empty((len(p), self.baseline_ohm.size))
        pressed = p[:, 2] > 0
        out[~pressed] = 0.0
        q = p[pressed]
        nodes = self.table.node_index(q)
        if nodes is not None:
            out[pressed] = self.table.values.reshape(-1, out.shape[1])[nodes]
        else:
            out[pressed] = self.table.evaluate(q, 0)[:, 0]
            self.rows += len(q)
        return out + self.baseline_ohm

    def pair_resistance_and_jacobian_ohm(self, x_mm, y_mm, depth_mm) -> tuple[np.ndarray, np.ndarray]:
        p = np.stack([np.asarray(v, float) for v in (x_mm, y_mm, depth_mm)], -1)
        values = self.table.evaluate(p, 1)
        self.rows += len(p)
        return values[:, 0] + self.baseline_ohm, values[:, 1:4].transpose(0, 2, 1)

    def pair_resistance_jacobian_hessian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        values = self.table.evaluate(p, 2)
        self.rows += len(p)
        return values[:, 0] + self.baseline_ohm, values[:, 1:4].transpose(0, 2, 1), hessian(values)


class HybridSkin:
    """The true skin's value and analytic Jacobian with the surrogate's Hessian: the polish's Newton model
    (`pair_resistance_jacobian_hessian`, so `invsolve.refine` takes S = sum_i r_i d2r_i from the table)."""

    has_analytic_jacobian = True

    def __init__(self, skin, table: SplineTable):
        self.skin = skin
        self.table = table
        self.rows = 0  # true-model rows (value and gradient)
        self.table_rows = 0

    def pair_resistance_ohm(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        return self.skin.pair_resistance_ohm(x_mm, y_mm, depth_mm)

    def pair_resistance_and_jacobian_ohm(self, x_mm, y_mm, depth_mm) -> tuple[np.ndarray, np.ndarray]:
        return self.skin.pair_resistance_and_jacobian_ohm(x_mm, y_mm, depth_mm)

    def pair_resistance_jacobian_hessian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        value = np.empty((len(p), self.table.coef.shape[-1]))
        jac = np.empty((*value.shape, 3))
        for start in range(0, len(p), GRADIENT_CHUNK):
            q = p[start : start + GRADIENT_CHUNK]
            value[start : start + GRADIENT_CHUNK], jac[start : start + GRADIENT_CHUNK] = (
                self.skin.pair_resistance_and_jacobian_ohm(q[:, 0], q[:, 1], q[:, 2])
            )
        lost = ~np.all(np.isfinite(jac), axis=(1, 2))
        if lost.any():  # a channel shut: the model's value as `model_dr` takes it, the table's Jacobian
            q = p[lost]
            shut = self.skin.pair_resistance_ohm(q[:, 0], q[:, 1], q[:, 2])
            value[lost] = np.where(np.isfinite(shut), shut, BIG_OHM)
            jac[lost] = self.table.evaluate(q, 1)[:, 1:4].transpose(0, 2, 1)
        self.rows += len(p)
        self.table_rows += len(p)
        return value, jac, hessian(self.table.evaluate(p, 2))


def _source_digest() -> str:
    """A hash of the model's and this module's source: a change to the code that computes dR changes the key."""
    from neatskin.skin import deformation, model, modelgrad, network

    digest = hashlib.sha256()
    for module in (deformation, model, modelgrad, network):
        digest.update(Path(str(module.__file__)).read_bytes())
    digest.update(Path(__file__).read_bytes())
    return digest.hexdigest()


def _plain(value):
    if is_dataclass(value) and not isinstance(value, type):
        return {k: _plain(v) for k, v in asdict(value).items() if k not in ("source", "description")}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def table_key(skin, lo, step, shape) -> str:
    """The cache key of a skin's table: every field of the skin model (its layout's geometry, fidelity, probe, pinch
    parameters, fabrication heights, ...; an FE kernel by its own key), the grid, the table format and the source
    of the code that computes dR."""
    spec = {f.name: _plain(getattr(skin, f.name)) for f in fields(skin) if f.name != "kernel"}
    kernel = getattr(skin, "kernel", None)
    spec["kernel"] = None if kernel is None else str(getattr(kernel, "key", repr(kernel)))
    text = json.dumps(
        {
            "format": TABLE_FORMAT,
            "source": _source_digest(),
            "skin": spec,
            "grid": {"lo": list(lo), "step": list(step), "shape": list(shape)},
        },
        sort_keys=True,
        default=repr,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _digest(values: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(values).tobytes()).hexdigest()


def build_table(skin, baseline_ohm, lo, hi, step_mm: float, n_depths: int) -> SplineTable:
    """The model's dR on the grid from lo to hi (x and y at about step_mm, n_depths depths), interpolated."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = [max(4, int(round((hi[a] - lo[a]) / step_mm)) + 1) for a in (0, 1)] + [max(4, n_depths)]
    step = (hi - lo) / (np.array(shape) - 1)
    axes = [lo[a] + step[a] * np.arange(shape[a]) for a in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = model_dr(skin, np.asarray(baseline_ohm, float), nodes).reshape(*shape, -1)
    return SplineTable.from_values(lo, step, values)


def load_table(skin, baseline_ohm, lo, hi, step_mm: float, n_depths: int, cache: Path | None) -> SplineTable:
    """`build_table`, through an on-disk cache in the folder `cache` (None: always built): a file whose key,
    shape or checksum does not match is rebuilt and replaced, never trusted."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = [max(4, int(round((hi[a] - lo[a]) / step_mm)) + 1) for a in (0, 1)] + [max(4, n_depths)]
    step = (hi - lo) / (np.array(shape) - 1)
    if cache is None:
        return build_table(skin, baseline_ohm, lo, hi, step_mm, n_depths)
    key = table_key(skin, lo.tolist(), step.tolist(), shape)
    path = Path(cache) / f"{key}.npz"
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as z:
                ok = str(z["key"]) == key and tuple(z["values"].shape[:3]) == tuple(shape)
                ok = (
                    ok
                    and _digest(z["values"]) == str(z["values_sha256"])
                    and _digest(z["coef"]) == str(z["coef_sha256"])
                )
                if ok:
                    return SplineTable(
                        (float(lo[0]), float(lo[1]), float(lo[2])),
                        (float(step[0]), float(step[1]), float(step[2])),
                        (int(shape[0]), int(shape[1]), int(shape[2])),
                        z["values"],
                        z["coef"],
                    )
        except Exception as exc:  # a truncated or foreign file: rebuilt below
            logger.warning("inversion table %s unreadable (%s): rebuilding it", path, exc)
        else:
            logger.warning("inversion table %s does not match its key or checksum: rebuilding it", path)
    started = time.perf_counter()
    table = build_table(skin, baseline_ohm, lo, hi, step_mm, n_depths)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(
            tmp,
            key=key,
            values=table.values,
            coef=table.coef,
            values_sha256=_digest(table.values),
            coef_sha256=_digest(table.coef),
        )
        os.replace(tmp, path)  # whole or not at all: a reader never sees a half-written table
    except OSError as exc:  # a cache that cannot be written costs the next run a rebuild, not this run its answer
        logger.warning("inversion table not cached in %s (%s): built for this run only", path.parent, exc)
        if tmp.parent.is_dir():
            tmp.unlink(missing_ok=True)
    logger.debug("inversion table %s built in %.2f s", path, time.perf_counter() - started)
    return table


def cache_dir() -> Path:
    """The tables' folder in the user cache (as the FE kernels': $NEATSKIN_CACHE, else the XDG cache)."""
    if os.environ.get("NEATSKIN_CACHE"):
        root = Path(os.environ["NEATSKIN_CACHE"])
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "neatskin"
    return root / "inversion-tables"

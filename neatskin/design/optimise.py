"""Electrode placement for a given channel layout: greedy plus exchange (Fedorov-style swaps) on a D- or
A-optimality criterion of the per-press Fisher information averaged over the press area, and the brute-force
search it is checked against on small grids.

Electrodes not driven float, so the information of a placement E is the sum over its pairs of per-pair terms
F(E) = sum_{a<b in E} G_ab, G_ab = j_ab j_ab^T / sigma_ab^2 (3 x 3 per press, theta = x, y, depth); the
criterion is taken on the position block with depth as nuisance (`bound.position_information`).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import numpy as np

from neatskin.design.bound import PairNoise, criterion, position_information
from neatskin.design.sensitivity import PressJacobian

log = logging.getLogger(__name__)

# A prior of 1 m standard deviation on each axis (1e-6 / mm^2): far below any useful information, it only keeps
# the criterion finite for placements that leave some press unseen (two electrodes, the start of the greedy).
RIDGE_PER_MM2 = 1e-6
MAX_EXCHANGE_ROUNDS = 200
BRUTE_FORCE_MAX_PLACEMENTS = 200_000


@dataclass(frozen=True)
class Placement:
    """Electrodes on candidate junctions (indices into the PressJacobian's junctions, sorted) and their score."""

    members: tuple[int, ...]
    score: float
    criterion: str
    evaluations: int


class PairInformation:
    """Per-pair Fisher information G_ab for candidate junctions, computed on demand from adjoint Jacobians."""

    def __init__(self, pj: PressJacobian, noise: PairNoise, depth_known: bool = False) -> None:
        self.pj = pj
        self.sigma = noise.std(pj.baseline_pair_ohm)
        self.depth_known = depth_known
        self.n_junctions = int(pj.junctions.shape[0])

    def block(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(presses, len(a), len(b), 3, 3); zero where a == b."""
        a, b = np.asarray(a, np.intp), np.asarray(b, np.intp)
        jac = self.pj.pair_jacobian(a[:, None], b[None, :])
        with np.errstate(divide="ignore", invalid="ignore"):
            w = jac / self.sigma[a[:, None], b[None, :]][None, ..., None]
        w = np.where(np.isfinite(w), w, 0.0)
        return w[..., :, None] * w[..., None, :]

    def placement(self, members) -> np.ndarray:
        """F(E): (presses, 3, 3)."""
        idx = np.asarray(members, np.intp)
        return self.block(idx, idx).sum(axis=(1, 2)) / 2.0

    def score(self, info3: np.ndarray, kind: str) -> np.ndarray:
        return criterion(position_information(info3, self.depth_known), kind, RIDGE_PER_MM2)


def _score_last_axis(table: PairInformation, info: np.ndarray, kind: str) -> np.ndarray:
    """info (presses, *k, 3, 3) -> criterion per k (press axis averaged)."""
    moved = np.moveaxis(info, 0, -3)  # (*k, presses, 3, 3)
    return table.score(moved, kind)


def greedy_exchange(table: PairInformation, count: int, kind: str = "D", restarts: int = 8, seed: int = 0) -> Placement:
    """Best placement of `count` electrodes found by greedy addition then pairwise exchange to a local optimum,
    and by exchange from `restarts` random placements (seeded); the best of these local optima."""
    n = table.n_junctions
    if not 2 <= count <= n:
        raise ValueError(f"cannot place {count} electrodes on {n} candidate junctions")
    members, evaluations = _greedy(table, count, kind)
    best, best_score, used = _exchange(table, members, kind)
    evaluations += used
    rng = np.random.default_rng([seed, count, n])
    for _ in range(restarts):
        start = sorted(int(i) for i in rng.choice(n, size=count, replace=False))
        found, score, used = _exchange(table, start, kind)
        evaluations += used
        if score < best_score - 1e-12 * abs(best_score):
            best, best_score = found, score
    return Placement(tuple(sorted(best)), float(table.score(table.placement(best), kind)), kind, evaluations)


def _greedy(table: PairInformation, count: int, kind: str) -> tuple[list[int], int]:
    """Greedy addition from the best single pair."""
    n = table.n_junctions
    everyone = np.arange(n)
    evaluations = 0
    best_pair, best_score = (0, 1), np.inf
    for a in range(n - 1):
        others = everyone[a + 1 :]
        scores = _score_last_axis(table, table.block(np.array([a]), others)[:, 0], kind)
        evaluations += others.size
        k = int(np.argmin(scores))
        if scores[k] < best_score:
            best_pair, best_score = (a, int(others[k])), float(scores[k])
    members = list(best_pair)
    info = table.placement(members)
    while len(members) < count:
        out = np.setdiff1d(everyone, members)
        gain = table.block(np.array(members), out).sum(axis=1)  # (presses, out, 3, 3)
        scores = _score_last_axis(table, info[:, None] + gain, kind)
        evaluations += out.size
        k = int(np.argmin(scores))
        members.append(int(out[k]))
        info = info + gain[:, k]
    return members, evaluations


def _exchange(table: PairInformation, members: list[int], kind: str) -> tuple[list[int], float, int]:
    """Best single swaps (one electrode moved to a free junction) until none improves; capped rounds."""
    members = list(members)
    everyone = np.arange(table.n_junctions)
    info = table.placement(members)
    score = float(table.score(info, kind))
    evaluations = 0
    for _ in range(MAX_EXCHANGE_ROUNDS):
        inside = np.array(members)
        out = np.setdiff1d(everyone, members)
        if out.size == 0:
            break
        g = table.block(inside, everyone)  # (presses, E, J, 3, 3)
        added = g.sum(axis=1)  # A_j = sum_{a in E} G_aj
        # F(E - e + j) = F(E) - A_e + A_j - G_ej
        swapped = info[:, None, None] - added[:, inside][:, :, None] + added[:, out][:, None, :] - g[:, :, out]
        scores = _score_last_axis(table, swapped, kind)
        evaluations += scores.size
        e, j = np.unravel_index(int(np.argmin(scores)), scores.shape)
        if not scores[e, j] < score - 1e-12 * abs(score):
            break
        members[int(e)] = int(out[j])
        info, score = swapped[:, e, j], float(scores[e, j])
    else:
        log.warning("exchange stopped after %d rounds without converging", MAX_EXCHANGE_ROUNDS)
    return members, score, evaluations


def brute_force(table: PairInformation, count: int, kind: str = "D", batch: int = 256) -> Placement:
    """The best placement of `count` electrodes over every combination of candidate junctions."""
    n = table.n_junctions
    total = _comb(n, count)
    if total > BRUTE_FORCE_MAX_PLACEMENTS:
        raise ValueError(f"{total} placements is too many for brute force (limit {BRUTE_FORCE_MAX_PLACEMENTS})")
    everyone = np.arange(n)
    full = table.block(everyone, everyone)  # (presses, J, J, 3, 3)
    best: tuple[int, ...] = ()
    best_score = np.inf
    combos = itertools.combinations(range(n), count)
    while chunk := list(itertools.islice(combos, batch)):
        idx = np.array(chunk)  # (b, count)
        info = full[:, idx[:, :, None], idx[:, None, :]].sum(axis=(2, 3)) / 2.0  # (presses, b, 3, 3)
        scores = _score_last_axis(table, info, kind)
        k = int(np.argmin(scores))
        if scores[k] < best_score:
            best, best_score = tuple(int(i) for i in idx[k]), float(scores[k])
    return Placement(best, best_score, kind, total)


def _comb(n: int, k: int) -> int:
    from math import comb

    return comb(n, k)

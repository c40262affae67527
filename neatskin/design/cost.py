"""What a design study costs before it runs: the work of each candidate in press evaluations (the unit every
stage of `evaluate.py` spends its time in: one press of the skin model against one candidate junction), turned
into seconds by one constant, for the estimate the command prints (and its limit) and for the progress bar's
share of each stage inside a candidate.

The constant was measured, not derived: grid5's candidates on the 2-core development machine took 4.6e-5 s per
press evaluation in one process at load ~9, i.e. about 9.2e-6 s on a free core if a process gets cores/(load+1) of
one. Scaled that way to the load at the start, the same candidates run again at load ~19 took 0.97x to 1.45x the
estimate (boundary 8, 12, 16 and optimised 8, 12 electrodes; the first candidate pays the imports). The optimiser's
greedy exchange is the one cost that is not press evaluations: it grows steeply with the electrode count (optimised
16 took 3.7x what its press evaluations give, 8 and 12 none extra), so it is a term restarts x count^3 x pool x
presses fitted to optimised 16 alone (it then overestimates 12). With it, grid5 in one process at load ~17-19: 553 s
measured, 549 s estimated. Two joblib workers ran 2 to 3 times longer than the load-scaled estimate (10 min at
load 11 rising to 17). The machine's load changes while a study runs: the estimate is a guide, not a promise.
"""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.design.candidates import Candidate, optimiser_junctions
from neatskin.design.study import Study

SECONDS_PER_PRESS_EVALUATION = 9.2e-6  # on a free core: measured under load, scaled (module docstring)
SECONDS_PER_CANDIDATE = 0.2  # fixed cost: layout, noise, report row (measured, same runs)
SECONDS_PER_JUNCTION_CUBED = 1e-10  # the dense grounded inverse, once per candidate (numpy inv, assumed)
OPTIMISER_UNITS = 1.24e-3  # per restart x count^3 x pool x press: fitted to grid5's optimised 16 (module docstring)
DEFAULT_LIMIT_S = 3600.0  # a study estimated above one hour needs --yes


@dataclass(frozen=True)
class CandidateWork:
    """A candidate's press evaluations per stage, in the order evaluate_candidate spends them."""

    junctions: int  # candidate junctions evaluated (the pool: all of them for the optimiser)
    jacobian: int
    learned: int
    inversion_library: int
    inversion_step: int  # per Gauss-Newton iteration (and once more for the final misfit)
    inversion_steps: int
    optimiser: int = 0  # the greedy exchange, in the same unit (fitted: module docstring)

    @property
    def total(self) -> int:
        steps = self.inversion_step * self.inversion_steps
        return self.jacobian + self.learned + self.inversion_library + steps + self.optimiser


def candidate_work(study: Study, candidate: Candidate) -> CandidateWork:
    presses = study.press_grid**2
    pool = (
        len(optimiser_junctions(candidate.nx, candidate.ny))
        if candidate.strategy == "optimised"
        else len(candidate.nodes)
    )
    electrodes = candidate.count if candidate.strategy == "optimised" else len(candidate.nodes)
    learned = study.learned.seeds * study.learned.positions * electrodes if study.learned.enabled else 0
    inv = study.inversion
    library = inv.library**2 * len(inv.depth_offsets_mm) * electrodes if inv.enabled else 0
    step = inv.draws * presses * inv.starts * electrodes if inv.enabled else 0
    return CandidateWork(
        junctions=pool,
        jacobian=presses * pool + (presses * electrodes if inv.enabled else 0),
        learned=learned,
        inversion_library=library,
        inversion_step=step,
        inversion_steps=inv.iterations + 1 if inv.enabled else 0,
        optimiser=(
            int(OPTIMISER_UNITS * max(study.restarts, 1) * candidate.count**3 * pool * presses)
            if candidate.strategy == "optimised"
            else 0
        ),
    )


def candidate_seconds(study: Study, candidate: Candidate) -> float:
    n = candidate.nx * candidate.ny
    work = candidate_work(study, candidate).total
    return SECONDS_PER_CANDIDATE + SECONDS_PER_JUNCTION_CUBED * n**3 + SECONDS_PER_PRESS_EVALUATION * work


def slowdown(load: float, cores: int, workers: int) -> float:
    """How much slower than on free cores: each of `workers` processes gets cores / (load + workers) of a core."""
    return max(1.0, (max(load, 0.0) + workers) / max(cores, 1))


def machine_load() -> tuple[float, int]:
    """(the 1-minute load average, the cores this process may use); (0, 1) where the OS does not say."""
    import os

    try:
        return os.getloadavg()[0], len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return 0.0, max(1, os.cpu_count() or 1)


def study_seconds(
    study: Study, candidates: list[Candidate], jobs: int, load: float = 0.0, cores: int | None = None
) -> float:
    """Estimated wall time: the candidates' seconds on free cores, shared over the workers (never fewer per worker
    than the largest candidate), times the slowdown the machine's load gives them."""
    each = [candidate_seconds(study, c) for c in candidates]
    if not each:
        return 0.0
    workers = max(1, min(jobs, len(each)))
    free = max(sum(each) / workers, max(each))
    return free * slowdown(load, cores or workers, workers)


BASIS = "press evaluations x 9.2e-6 s on a free core, measured on grid5, scaled by the load at the start"

"""What a design study costs before it runs: the work of each candidate in press evaluations (the unit every
stage of `evaluate.py` spends its time in: one press of the skin model against one candidate junction), turned
into seconds by one constant, for the estimate the command prints (and its limit) and for the progress bar's
share of each stage inside a candidate.

The constant was measured, not derived: grid5's candidates (8 and 12 boundary electrodes, with and without the
learned error and the inversion) on the 2-core development machine under load ~9 took 3.6e-5 to 4.6e-5 s per
press evaluation, the inversion included (its Gauss-Newton steps call the same model). An idle machine runs
faster: the estimate is an upper guide, good to a factor of about 3, not a promise.
"""

from __future__ import annotations

from dataclasses import dataclass

from neatskin.design.candidates import Candidate
from neatskin.design.evaluate import optimiser_junctions
from neatskin.design.study import Study

SECONDS_PER_PRESS_EVALUATION = 4.6e-5  # measured (module docstring)
SECONDS_PER_CANDIDATE = 0.2  # fixed cost: layout, noise, report row (measured, same runs)
SECONDS_PER_JUNCTION_CUBED = 1e-10  # the dense grounded inverse, once per candidate (numpy inv, assumed)
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

    @property
    def total(self) -> int:
        return self.jacobian + self.learned + self.inversion_library + self.inversion_step * self.inversion_steps


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
    )


def candidate_seconds(study: Study, candidate: Candidate) -> float:
    n = candidate.nx * candidate.ny
    work = candidate_work(study, candidate).total
    return SECONDS_PER_CANDIDATE + SECONDS_PER_JUNCTION_CUBED * n**3 + SECONDS_PER_PRESS_EVALUATION * work


def study_seconds(study: Study, candidates: list[Candidate], jobs: int) -> float:
    """Estimated wall time: the candidates' seconds shared over the workers (never fewer per worker than the
    largest candidate)."""
    each = [candidate_seconds(study, c) for c in candidates]
    if not each:
        return 0.0
    return max(sum(each) / max(1, min(jobs, len(each))), max(each))


BASIS = "press evaluations x 4.6e-5 s, measured on grid5; the workers' cores assumed free"

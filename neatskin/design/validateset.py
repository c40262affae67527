"""Which candidates `neatskin design validate` checks: the study's fixed placements (at least 3), plus its optimised
placements when a run of this very study has produced them in OUT (`parts/<candidate_id>.parquet`, else
`candidates.parquet`, with OUT's `study.json` equal to the study's fingerprint); otherwise one line saying they are left out and the command that
makes them. An optimised placement that is one of the fixed ones (8 on a 5 x 5: the paper's ring) is not repeated.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from neatskin.design.candidates import Candidate, expand
from neatskin.design.study import Study


@dataclass(frozen=True)
class ValidationSet:
    """The candidates to check (fixed ones first, in study order, then the optimised ones found) and a note: one
    line on the optimised candidates left out and why (None when every one is in, or the study has none)."""

    candidates: tuple[Candidate, ...]
    note: str | None = None


def skin_key(candidate: Candidate) -> tuple[float, ...]:
    """What makes two candidates the same skin, probe and depth (placements compete only on the same skin)."""
    c = candidate
    return (c.nx, c.ny, c.pitch_mm, c.channel_width_mm, c.channel_height_mm, c.probe_diameter_mm, c.depth_mm)


def label(candidate: Candidate) -> str:
    return f"{candidate.placement.rstrip('-')} {candidate.count}"


def fixed_candidates(study: Study) -> list[Candidate]:
    from neatskin.errors import ConfigError

    fixed = [c for c in expand(study) if c.strategy != "optimised" and c.nodes]
    if len(fixed) < 3:
        raise ConfigError(
            f"the study has {len(fixed)} candidates with fixed placements; a ranking needs at least 3",
            file=study.source,
            field="electrodes.strategies",
            fix="add boundary, interior or every_k placements (or more counts)",
        )
    return fixed


def _make_command(study: Study, out_dir: Path, fresh: bool) -> str:
    source = study.source if study.source != "<memory>" else "STUDY.toml"
    if fresh:
        return f"make them with `neatskin design study {source} --out {out_dir}`"
    return f"make them with `neatskin design study {source} --out NEW_DIR`, then validate with `--out NEW_DIR`"


def _written_placements(out_dir: Path) -> dict[str, str]:
    """candidate_id -> electrode_nodes ("i,j;i,j;...") of every candidate the run wrote: its durable parts (a run
    still going or killed), else candidates.parquet (a committed result without its parts)."""
    import pandas as pd

    from neatskin.design.study import PARTS

    parts = sorted((out_dir / PARTS).glob("*.parquet")) if (out_dir / PARTS).is_dir() else []
    tables = [pd.read_parquet(p, columns=["candidate_id", "electrode_nodes"]) for p in parts]
    if not tables and (out_dir / "candidates.parquet").is_file():
        tables = [pd.read_parquet(out_dir / "candidates.parquet", columns=["candidate_id", "electrode_nodes"])]
    return {str(r.candidate_id): str(r.electrode_nodes) for t in tables for r in t.itertuples()}


def run_placements(study: Study, out_dir: Path, fixed: list[Candidate]) -> ValidationSet:
    """The optimised candidates of `study` with the placements its run wrote in out_dir, and the note."""
    from neatskin.design.evaluate import canonical_nodes
    from neatskin.design.study import FINGERPRINT, study_fingerprint

    wanted = [c for c in expand(study) if c.strategy == "optimised"]
    if not wanted:
        return ValidationSet(tuple(fixed))
    left_out = "the optimised candidates are left out"
    fingerprint_path = out_dir / FINGERPRINT
    if not fingerprint_path.is_file():
        note = f"{left_out}: {out_dir} holds no run of this study; {_make_command(study, out_dir, True)}"
        return ValidationSet(tuple(fixed), note)
    try:
        previous = json.loads(fingerprint_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        previous = None
    fingerprint = study_fingerprint(study)
    if previous != fingerprint:
        before = previous if isinstance(previous, dict) else {}
        changed = sorted(k for k in fingerprint if before.get(k) != fingerprint[k]) or ["format"]
        note = (
            f"{left_out}: {out_dir} holds a run of another study config (changed: {', '.join(changed)}); "
            f"{_make_command(study, out_dir, False)}"
        )
        return ValidationSet(tuple(fixed), note)
    same = {(skin_key(c), canonical_nodes(c.nodes)): c for c in fixed}
    placements = _written_placements(out_dir)
    found: list[Candidate] = []
    missing: list[str] = []
    repeated: list[str] = []
    for candidate in wanted:
        text = placements.get(candidate.candidate_id)
        if text is None:
            missing.append(label(candidate))
            continue
        nodes = tuple((int(i), int(j)) for i, j in (n.split(",") for n in text.split(";")))
        twin = same.get((skin_key(candidate), canonical_nodes(nodes)))
        if twin is not None:
            repeated.append(f"{label(candidate)} is {label(twin)}'s placement")
            continue
        found.append(dataclasses.replace(candidate, nodes=nodes))
    notes = []
    if missing:
        notes.append(
            f"{', '.join(missing)} left out: not yet computed in {out_dir}; {_make_command(study, out_dir, True)}"
        )
    if repeated:
        notes.append("; ".join(repeated) + " (not repeated)")
    return ValidationSet(tuple(fixed) + tuple(found), "; ".join(notes) or None)


def validation_set(study: Study, out_dir: Path | None) -> ValidationSet:
    """The fixed candidates, and with out_dir the optimised ones its run produced (else a note saying why not)."""
    fixed = fixed_candidates(study)
    if out_dir is None:
        if any(c.strategy == "optimised" for c in expand(study)):
            return ValidationSet(tuple(fixed), "the optimised candidates are left out: no study folder given")
        return ValidationSet(tuple(fixed))
    return run_placements(study, Path(out_dir), fixed)

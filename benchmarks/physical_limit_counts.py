"""The physical limit's bounds of finished dry runs, recomputed with this checkout: per run and bound, the positions
where it is infinite, finite, beyond the probe radius, and its median, beside the file the run wrote.

    python benchmarks/physical_limit_counts.py RUN [RUN ...]

Each run folder is read only: its inputs/protocol.toml (seed, scene, layout) gives the plan, the dry skin and the
DAQ as `neatskin campaign run` built them, and `neatskin.rig.physlimit.physical_limit_table` (what the dry rig
writes as physical_limit.parquet, a pure function of them: no press) is computed again. The stored file's columns
are printed beside, so a changed rule shows as a changed count. The last lines pool the runs: per bound the range
over runs of the infinite count and of the median, and the median of the medians.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

COLUMNS = ("crb_mm", "crb_nuisance_mm", "landing_bound_known_skin_mm", "landing_bound_mm")
PROBE_RADIUS_MM = 2.75


def recompute(run: Path):
    """physical_limit_table of the run's own protocol, plan, dry skin and DAQ, as a pandas frame."""
    from neatskin.rig.dryrig import dry_scene
    from neatskin.rig.folder import load_inputs
    from neatskin.rig.physlimit import physical_limit_table
    from neatskin.rig.plan import build_plan
    from neatskin.sim.daq import NoiseModel, SimulatedDAQ
    from neatskin.sim.dryscene import dry_skin, interface_noise

    protocol = load_inputs(run)  # the run's copies of its layout, wiring and printer, as `campaign resume` reads them
    plan = build_plan(protocol)
    dry = dry_scene(protocol, plan)
    skin = dry_skin(dry)
    unpressed = np.asarray(skin.baseline_pair_resistance_ohm, float)
    noise = interface_noise(NoiseModel() if dry.scene.noise else NoiseModel.none(), dry.scene)
    # physlimit reads the DAQ's config and noise and sets each state itself (as tests/test_physlimit.py does)
    daq = SimulatedDAQ(dry.daq, lambda t: np.broadcast_to(unpressed, (len(t), unpressed.size)), noise=noise)
    return physical_limit_table(protocol, plan, skin, daq).to_pandas(), protocol.seed


def counts(values: np.ndarray) -> str:
    infinite = int(np.count_nonzero(np.isinf(values)))
    beyond = int(np.count_nonzero(values > PROBE_RADIUS_MM))
    return (
        f"infinite {infinite:3d}, finite {values.size - infinite:3d}, > probe radius {beyond:3d}, "
        f"median {np.median(values):.3g} mm"
    )


def main() -> None:
    runs = [Path(a) for a in sys.argv[1:]]
    if not runs:
        raise SystemExit(__doc__)
    pooled: dict[str, list[tuple[int, float]]] = {c: [] for c in COLUMNS}
    for run in runs:
        new, seed = recompute(run)
        old = pq.read_table(run / "physical_limit.parquet").to_pandas()
        print(f"{run} (seed {seed}, {len(new)} positions)")
        for column in COLUMNS:
            values = new[column].to_numpy(float)
            pooled[column].append((int(np.count_nonzero(np.isinf(values))), float(np.median(values))))
            print(f"  {column:<28} now:    {counts(values)}")
            print(f"  {'':<28} stored: {counts(old[column].to_numpy(float))}")
        landing, known = new["landing_bound_mm"].to_numpy(float), new["landing_bound_known_skin_mm"].to_numpy(float)
        crb = new["crb_mm"].to_numpy(float)
        print(
            f"  more nuisances below fewer: landing < known skin at {int(np.sum(landing < known))}, "
            f"known skin < crb at {int(np.sum(known < crb))}; finite where crb is infinite: "
            f"{int(np.sum(np.isfinite(landing) & np.isinf(crb)))}"
        )
    for column, per_run in pooled.items():
        infinite = [i for i, _ in per_run]
        medians = [m for _, m in per_run]
        print(
            f"{column:<28} over {len(per_run)} runs: infinite {min(infinite)} to {max(infinite)}, median "
            f"{min(medians):.3g} to {max(medians):.3g} mm (median of the medians {np.median(medians):.3g} mm)"
        )


if __name__ == "__main__":
    main()

"""The plan of a campaign: the protocol's press program, mux sweep and timing, built and checked before anything moves.

`build_plan` is the one place a protocol becomes the work the runner does (the G-code press blocks, the
sweep, the sweeps recorded per press, the printer's time per phase); the folder, the rig builders, the
physical limit and the runner all take the `Plan` it returns instead of building any of it again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neatskin.acquisition.sequence import Sweep, SweepTiming, build_sweep
from neatskin.errors import ConfigError
from neatskin.gcode.motion import phase_durations_s
from neatskin.gcode.program import PressProgram
from neatskin.gcode.spec import build_from_spec
from neatskin.rig.protocol import CampaignProtocol

# `campaign check` warns above this hold (the config allows up to 3600 s). Any workable hold is at least two sweeps
# (0.68 s for the paper's 28 pairs): that many milliseconds typed as seconds is >= 683 s, so every ms/s slip of a
# workable hold lands above 60 s, while a deliberate long hold (creep, relaxation) of up to a minute stays quiet.
LONG_HOLD_S = 60.0


@dataclass(frozen=True)
class Plan:
    program: PressProgram
    sweep: Sweep
    n_sweeps: int  # sweeps recorded per press, from parking above the target to lifted
    hold_s: float
    printer_time_s: float  # the G-code's estimate for the whole campaign
    phase_s: np.ndarray  # (presses, [travel, descend, press, lift]) printer seconds, gcode.motion.phase_durations_s

    @property
    def n_presses(self) -> int:
        return len(self.program.presses)

    @property
    def press_interval_s(self) -> float:
        """The G-code's own printer time per press (the whole campaign's estimate over its presses)."""
        return self.printer_time_s / max(self.n_presses, 1)

    def long_hold_warning(self) -> str | None:
        """One line when the hold is longer than LONG_HOLD_S (a ms/s slip?): what it costs and the likely fix."""
        if self.hold_s <= LONG_HOLD_S:
            return None
        holds_h = self.hold_s * self.n_presses / 3600
        return (
            f"hold_s = {self.hold_s:g} s is over {LONG_HOLD_S:g} s: the holds alone take {holds_h:.2f} h of the "
            f"{self.printer_time_s / 3600:.2f} h; if it was meant in milliseconds, set hold_s = {self.hold_s / 1000:g}"
        )

    def commanded_mm(self, depth_mm: float) -> np.ndarray:
        """(presses, 3): where press k presses (x, y, depth), in press-id order; no block's G-code is formatted."""
        ids = self.program.presses.position_ids
        xs = np.asarray(self.program.positions.x_mm, float)
        ys = np.asarray(self.program.positions.y_mm, float)
        return np.column_stack([xs[ids], ys[ids], np.full(ids.size, depth_mm)])


def build_plan(protocol: CampaignProtocol) -> Plan:
    """Everything the runner will do, checked before any motion (bounds, hold long enough to sample)."""
    program, _, _ = build_from_spec(
        protocol.press, hold_in_gcode=False, layout=protocol.layout, profile=protocol.printer
    )
    acq = protocol.acquisition
    sweep = build_sweep(
        protocol.wiring,
        SweepTiming(rate_hz=acq.rate_hz, settle_samples=acq.settle_samples, live_samples=acq.live_samples),
    )
    hold_s = protocol.press.press.hold_s
    min_hold = 2 * sweep.duration_s
    if hold_s < min_hold:
        raise ConfigError(
            f"hold_s = {hold_s} s holds the probe for less than two sweeps of the {sweep.n_pairs} "
            f"pairs ({min_hold:.3f} s), so no whole sweep would be recorded at depth",
            file=str(protocol.path),
            field="press.hold_s",
            fix=f"set hold_s >= {math.ceil(min_hold * 10) / 10}",
        )
    durations = phase_durations_s(program, protocol.printer)  # (presses, [travel, descend, press, lift])
    per_press = durations[:, 1:].sum(axis=1) + hold_s
    n_sweeps = int(math.ceil((per_press.max() + 0.5) / sweep.duration_s))
    total = float(durations.sum() + hold_s * len(program.presses))
    return Plan(program, sweep, n_sweeps, hold_s, total, durations)

"""The end-of-run summary line and the printer-time wording `campaign check` shares with it: durations a reader takes
in at once (seconds, minutes, hours), `press` or `presses`, and a dry run's speed against the wall."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from neatskin.rig.runner import CampaignResult


def run_summary(result: CampaignResult) -> str:
    rig_s = result.printer_time_s * result.written_now / result.planned if result.planned else 0.0
    state = (
        "interrupted (resume with: neatskin campaign resume " + str(result.folder) + ")"
        if result.completed < result.planned
        else "complete"
    )
    text = (
        f"campaign {state}: {result.completed}/{result.planned} presses in {result.folder} "
        f"({result.written_now} written now, {result.flagged} flagged); wall {duration_text(result.wall_s)}; "
        f"{printer_time_text(rig_s, result.written_now, 'written now')}"
    )
    if not result.dry_run:  # a real printer runs in real time: its share of the wall is no speed, say nothing
        return text
    ratio = rig_s / result.wall_s if result.wall_s > 0 else float("inf")
    return f"{text}, {times_text(ratio)} this wall time (the simulated printer runs faster than real time)"


def times_text(ratio: float) -> str:
    """A ratio as `33x`, `2.5x` or `0.6x`: two significant figures below 10."""
    return f"{ratio:.0f}x" if ratio >= 10 or not math.isfinite(ratio) else f"{ratio:.2g}x"


def duration_text(seconds: float) -> str:
    """A duration a reader takes in at once: `8.0 s`, `2.5 min`, `6.05 h` (an hour or more, as campaign check
    has always given a campaign's)."""
    if seconds < 59.5:
        return f"{seconds:.1f} s" if seconds < 9.95 else f"{seconds:.0f} s"
    if seconds < 3570:
        return f"{seconds / 60:.1f} min" if seconds < 597 else f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.2f} h"


def printer_time_text(seconds: float, presses: int, which: str = "") -> str:
    """The one wording of the printer-time figure, in `campaign check` and at the end of a run (they agree)."""
    what = f"the {presses} {'press' if presses == 1 else 'presses'}{f' {which}' if which else ''}"
    return (
        f"printer time {duration_text(seconds)} for {what} (motion and holds from the G-code machine model; "
        "homing and DAQ recording not included)"
    )

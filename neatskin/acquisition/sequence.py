"""The mux switching sequence of one sweep of S, sample by sample on the shared sample clock (pure functions).

A sweep visits every pair of S once. Each visit is a slot of three phases:

    break   (break_samples, >= 2)   every chip inhibited; the address lines change halfway
    settle  (settle_samples)        the pair's chip enabled, the switch settling: discarded
    live    (live_samples)          the pair measured

so the address lines only ever change while every chip has been inhibited for at least one
sample before and stays inhibited for at least one sample after (break-before-make), and at
most one chip is enabled on any sample (one pair live at a time). The default live window,
100 samples at 10 kHz, is 10 whole periods of the 1 kHz excitation.

Sample n of a sweep is at time n / rate_hz after the sweep starts; the DAQ repeats the same
line table for consecutive sweeps (the first slot's break starts from the last slot's address,
so the table tiles without an extra address change).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from neatskin.acquisition.wiring import ADDRESSES_PER_CHIP, Wiring
from neatskin.errors import ConfigError, Problem

ORDERS = ("pairs", "gray")


@dataclass(frozen=True)
class SweepTiming:
    """Sample counts of one slot, and the sample clock."""

    rate_hz: float = 10_000.0
    settle_samples: int = 20
    live_samples: int = 100  # 10 periods of 1 kHz at 10 kHz
    break_samples: int = 2

    def __post_init__(self) -> None:
        problems = []
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            problems.append(("rate_hz", f"rate_hz must be > 0, got {self.rate_hz!r}", "set rate_hz, e.g. 10000"))
        for name, low in (("settle_samples", 0), ("live_samples", 1), ("break_samples", 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                problems.append(
                    (
                        name,
                        f"{name} must be an integer >= {low}, got {value!r}",
                        f"set {name} >= {low}" + (" (break-before-make needs 2)" if low == 2 else ""),
                    )
                )
        if problems:
            raise ConfigError(problems=[Problem(m, "<sweep timing>", f, x) for f, m, x in problems])

    @property
    def slot_samples(self) -> int:
        return self.break_samples + self.settle_samples + self.live_samples


@dataclass(frozen=True, eq=False)
class Sweep:
    """One sweep of S: the per-sample line table and, for every pair, where it is live.

    Arrays indexed by pair follow layout.pairs order; `order` gives the visiting order.
    """

    line_names: tuple[str, ...]
    timing: SweepTiming
    order: np.ndarray  # (pairs,) pair indices in visiting order
    lines: np.ndarray = field(repr=False)  # (samples, lines) bool
    pair_of_sample: np.ndarray = field(repr=False)  # (samples,) int, -1 while every chip is inhibited
    settle_windows: np.ndarray = field(repr=False)  # (pairs, 2) [start, stop) sample, discarded
    live_windows: np.ndarray = field(repr=False)  # (pairs, 2) [start, stop) sample, measured
    chip: np.ndarray = field(repr=False)  # (pairs,)
    address: np.ndarray = field(repr=False)  # (pairs,)

    @property
    def n_samples(self) -> int:
        return int(self.lines.shape[0])

    @property
    def n_pairs(self) -> int:
        return int(self.order.shape[0])

    @property
    def rate_hz(self) -> float:
        return self.timing.rate_hz

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.timing.rate_hz

    @cached_property
    def is_live(self) -> np.ndarray:
        """(samples,) bool: the sample is in a live (measured) window."""
        live = np.zeros(self.n_samples, dtype=bool)
        live[self.live_sample_index.ravel()] = True
        return live

    @cached_property
    def live_sample_index(self) -> np.ndarray:
        """(pairs, live_samples) sample indices of each pair's live window."""
        return self.live_windows[:, :1] + np.arange(self.timing.live_samples)[None, :]

    def line_transitions(self) -> int:
        """Number of digital line edges in one sweep, counting the wrap to the next sweep."""
        return int(np.count_nonzero(self.lines != np.roll(self.lines, 1, axis=0)))


def visiting_order(wiring: Wiring, order: str = "pairs") -> np.ndarray:
    """Pair indices in visiting order.

    "pairs": layout.pairs order. "gray": chip by chip, addresses in a reflected Gray code that
    snakes between chips (0,1,3,2 then 2,3,1,0, ...), so only one address line changes per
    switch and none when moving to the next chip.
    """
    if order not in ORDERS:
        raise ConfigError(f"unknown sweep order {order!r}", field="order", fix=f"use one of {', '.join(ORDERS)}")
    if order == "pairs":
        return np.arange(wiring.n_pairs)
    gray = [0, 1, 3, 2][:ADDRESSES_PER_CHIP]
    slot = {(r.chip, r.address): r.pair_index for r in wiring.routes}
    out: list[int] = []
    forward = True
    for c in range(wiring.n_chips):
        used = [k for k in (gray if forward else gray[::-1]) if (c, k) in slot]
        if not used:
            continue
        out += [slot[(c, k)] for k in used]
        forward = not forward
    return np.array(out, dtype=np.intp)


def build_sweep(wiring: Wiring, timing: SweepTiming = SweepTiming(), order: str = "pairs") -> Sweep:
    """The line table and windows of one sweep of S through the wiring (pure, vectorised)."""
    visit = visiting_order(wiring, order)
    n_slots = len(visit)
    chip = np.array([r.chip for r in wiring.routes], dtype=np.intp)
    address = np.array([r.address for r in wiring.routes], dtype=np.intp)
    b, s = timing.break_samples, timing.settle_samples
    slot_len = timing.slot_samples
    n = n_slots * slot_len
    slot_of_sample = np.repeat(np.arange(n_slots), slot_len)
    phase = np.tile(np.arange(slot_len), n_slots)
    connected = phase >= b
    # address: the previous slot's until halfway through the break, then this slot's
    addr_of_slot = address[visit]
    prev_addr = np.roll(addr_of_slot, 1)
    addr = np.where(phase < b // 2, prev_addr[slot_of_sample], addr_of_slot[slot_of_sample])
    lines = np.ones((n, 2 + wiring.n_chips), dtype=bool)
    lines[:, 0] = (addr & 1).astype(bool)
    lines[:, 1] = (addr & 2).astype(bool)
    chip_of_sample = chip[visit][slot_of_sample]
    rows = np.flatnonzero(connected)
    lines[rows, 2 + chip_of_sample[rows]] = False  # inhibit low = chip enabled
    pair_of_sample = np.where(connected, visit[slot_of_sample], -1)
    slot_start = np.empty(wiring.n_pairs, dtype=np.int64)
    slot_start[visit] = np.arange(n_slots) * slot_len
    settle = np.stack([slot_start + b, slot_start + b + s], axis=1)
    live_w = np.stack([slot_start + b + s, slot_start + slot_len], axis=1)
    return Sweep(wiring.line_names, timing, visit, lines, pair_of_sample, settle, live_w, chip, address)


def check_sweep(sweep: Sweep) -> list[str]:
    """Every violation of the switching rules, sample by sample (empty when the sweep is sound)."""
    issues = []
    inhibit = sweep.lines[:, 2:]
    enabled = (~inhibit).sum(axis=1)
    if np.any(enabled > 1):
        issues.append(f"two chips enabled at samples {np.flatnonzero(enabled > 1)[:5].tolist()}")
    addr_change = np.any(sweep.lines[:, :2] != np.roll(sweep.lines[:, :2], 1, axis=0), axis=1)
    all_inhibited = inhibit.all(axis=1)
    guarded = all_inhibited & np.roll(all_inhibited, 1)
    bad = np.flatnonzero(addr_change & ~guarded)
    if bad.size:
        issues.append(
            f"address changes without every chip inhibited before and during it at samples {bad[:5].tolist()}"
        )
    visits = np.bincount(sweep.pair_of_sample[sweep.pair_of_sample >= 0], minlength=sweep.n_pairs)
    starts = np.count_nonzero(np.diff(np.concatenate([[-1], sweep.pair_of_sample, [-1]])) != 0)
    if np.any(visits != sweep.timing.settle_samples + sweep.timing.live_samples):
        issues.append("some pair is not connected for exactly settle + live samples")
    if starts != 2 * sweep.n_pairs:
        issues.append("some pair is connected in more than one stretch")
    return issues

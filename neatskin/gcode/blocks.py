"""Press blocks made when they are asked for: a campaign's presses as a few numbers each, their G-code on demand.

A `PressBlocks` holds, per press, only its ids and its printer-frame target (32 bytes), and
the text every press shares once (`PressTemplate`); each `PressBlock` with its phases' lines is
formatted when it is indexed or iterated and dropped when the caller is done with it. A
28,000-press program therefore holds 0.9 MB of numbers instead of 46 MB of G-code text (about
1.7 kB a press), and the lines are byte for byte the ones a stored block had. Every limit is checked on the numbers
(`bounds.check_press_plan`) before a block exists, so formatting cannot fail later.

A view (`presses[a:b]`, `presses.excluding(done)`) shares the numbers and selects rows. Its last
block is made once and kept, so `block is presses[-1]` holds for the block an iteration yields last.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np

from neatskin.gcode import emit
from neatskin.gcode.positions import PositionSet


@dataclass(frozen=True)
class Phase:
    name: str
    lines: tuple[str, ...]
    acquire: str | None = None


@dataclass(frozen=True)
class PressBlock:
    press_id: int
    position_id: int
    repeat: int
    x_mm: float  # sensor frame
    y_mm: float
    phases: tuple[Phase, ...]
    feature: str = ""
    printer_xyz_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the press target in the printer frame

    def phase(self, name: str) -> Phase:
        for phase in self.phases:
            if phase.name == name:
                return phase
        raise KeyError(name)


@dataclass(frozen=True)
class PressTemplate:
    """The G-code every press shares: its moves to the safe height, the surface and the press depth."""

    safe_line: str  # G0 to the safe height (travel's first move, and the lift)
    contact_line: str  # G1 down to the skin's surface
    press_line: str  # G1 on to the press depth, at the press feed
    hold_lines: tuple[str, ...]  # G4 in a file for standalone streaming, () for the runner
    travel_feed: str  # the F word of the xy travel move
    z_press_mm: float  # the press target's z in the printer frame

    def block(
        self,
        press_id: int,
        position_id: int,
        repeat: int,
        printer_x_mm: float,
        printer_y_mm: float,
        positions: PositionSet,
    ) -> PressBlock:
        """One press's block, its four phases' lines formatted now (the target is already bounds-checked)."""
        marker = emit.marker
        travel = f"G0 X{emit.fmt(printer_x_mm)} Y{emit.fmt(printer_y_mm)} F{self.travel_feed}"
        phases = (
            Phase("travel", (marker(press_id, "travel"), self.safe_line, travel, "M400"), "baseline"),
            Phase("descend", (marker(press_id, "descend"), self.contact_line, "M400")),
            Phase("press", (marker(press_id, "press"), self.press_line, *self.hold_lines, "M400"), "pressed"),
            Phase("lift", (marker(press_id, "lift"), self.safe_line, "M400")),
        )
        return PressBlock(
            press_id,
            position_id,
            repeat,
            positions.x_mm[position_id],
            positions.y_mm[position_id],
            phases,
            positions.features[position_id],
            (printer_x_mm, printer_y_mm, self.z_press_mm),
        )


class PressBlocks(Sequence[PressBlock]):
    """The presses of a program in execution order, each block formatted when asked for (see the module)."""

    def __init__(
        self,
        template: PressTemplate,
        positions: PositionSet,
        position_ids: np.ndarray,
        repeats: np.ndarray,
        printer_x_mm: np.ndarray,
        printer_y_mm: np.ndarray,
        rows: np.ndarray | None = None,
    ) -> None:
        """Press k of the program is press id k at position_ids[k] (printer target printer_x/y_mm[k]);
        `rows` selects the presses of a view (None: all, in order)."""
        self._template = template
        self._positions = positions
        self._position_ids = np.asarray(position_ids, dtype=np.int64)
        self._repeats = np.asarray(repeats, dtype=np.int64)
        self._x = np.asarray(printer_x_mm, dtype=float)
        self._y = np.asarray(printer_y_mm, dtype=float)
        self._rows = None if rows is None else np.asarray(rows, dtype=np.int64)
        self._last: PressBlock | None = None

    @property
    def template(self) -> PressTemplate:
        return self._template

    @property
    def press_ids(self) -> np.ndarray:
        """The press ids of this sequence, in order (a copy)."""
        return np.arange(len(self._position_ids)) if self._rows is None else self._rows.copy()

    @property
    def position_ids(self) -> np.ndarray:
        """The position id of each press of this sequence, in order (a copy)."""
        return self._position_ids.copy() if self._rows is None else self._position_ids[self._rows]

    def __len__(self) -> int:
        return len(self._position_ids) if self._rows is None else len(self._rows)

    @overload
    def __getitem__(self, index: int) -> PressBlock: ...

    @overload
    def __getitem__(self, index: slice) -> PressBlocks: ...

    def __getitem__(self, index: int | slice) -> PressBlock | PressBlocks:
        if isinstance(index, slice):
            return self._view(self.press_ids[index])
        n = len(self)
        i = int(index)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"press index {index} out of range for {n} presses")
        if i == n - 1:
            if self._last is None:
                self._last = self._make(self._row(i))
            return self._last
        return self._make(self._row(i))

    def __iter__(self) -> Iterator[PressBlock]:
        for i in range(len(self)):
            yield self[i]

    def excluding(self, press_ids: Collection[int]) -> PressBlocks:
        """The presses of this sequence whose id is not in `press_ids` (e.g. those a resumed campaign has)."""
        ids = self.press_ids
        if not press_ids:
            return self._view(ids)
        done = np.fromiter((int(i) for i in press_ids), dtype=np.int64, count=len(press_ids))
        return self._view(ids[~np.isin(ids, done)])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Sequence) or isinstance(other, str):
            return NotImplemented
        if len(self) != len(other):
            return False
        if isinstance(other, PressBlocks) and self._same_numbers(other):
            return True
        return all(a == b for a, b in zip(self, other, strict=True))

    __hash__ = None  # type: ignore[assignment]  # equal by content, like the tuple it replaces

    def __repr__(self) -> str:
        return f"PressBlocks({len(self)} presses)"

    def _row(self, i: int) -> int:
        return i if self._rows is None else int(self._rows[i])

    def _make(self, k: int) -> PressBlock:
        return self._template.block(
            k, int(self._position_ids[k]), int(self._repeats[k]), float(self._x[k]), float(self._y[k]), self._positions
        )

    def _view(self, rows: np.ndarray) -> PressBlocks:
        return PressBlocks(
            self._template, self._positions, self._position_ids, self._repeats, self._x, self._y, rows=rows
        )

    def _same_numbers(self, other: PressBlocks) -> bool:
        return (
            self._template == other._template
            and self._positions == other._positions
            and np.array_equal(self.press_ids, other.press_ids)
            and np.array_equal(self._position_ids, other._position_ids)
            and np.array_equal(self._repeats, other._repeats)
            and np.array_equal(self._x, other._x)
            and np.array_equal(self._y, other._y)
        )

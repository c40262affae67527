"""The mux board as data: which electrode sits on which pin of which dual 4:1 mux, and which digital lines drive it.

A board is a set of MAX4052-class dual 4:1 multiplexers sharing two address lines (A, B)
and one inhibit line per chip (high = every switch of that chip open). Section X of a chip
connects the source/sense "+" line to the electrode wired on pin Xk, section Y the "-"
line to the electrode on pin Yk, for address k = 2B + A. Chip c at address k therefore
routes one electrode pair; in the paper wiring, pair p of S (layout.pairs order) is chip
c = p // 4 at address k = p % 4.

The wiring file (protocols/wiring/*.toml):

    layout = "../skins/paper.toml"     # optional, relative to this file
    [lines]
    A = "port0/line0"
    B = "port0/line1"
    [[chips]]
    name = "U1"
    inhibit = "port0/line2"
    pins = { X0 = 1, Y0 = 2, X1 = 1, Y1 = 3, X2 = 1, Y2 = 4, X3 = 1, Y3 = 5 }
    [electrical]                       # optional; MAX4052 at +-8 V by default
    supply_positive_v = 8.0
    supply_negative_v = -8.0
    r_on_ohm = 100.0
    r_on_mismatch_ohm = 10.0

`load_wiring(path, layout)` refuses every mistake a technician can make in it, each with
one Problem naming the file, the field and the fix. Nothing here knows there are 28 pairs.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from neatskin.config import parse_tables
from neatskin.config.files import ChipEntry, LinesTable, WiringFile
from neatskin.config.files import ElectricalTable as MuxElectrical
from neatskin.config.kinds import wrong_kind_problem
from neatskin.errors import ConfigError, Problem, raise_problems
from neatskin.layout import ElectrodePair, Layout
from neatskin.tomlfile import read_toml, resolve_path

ADDRESSES_PER_CHIP = 4
_PIN_RE = re.compile(r"^([XY])([0-9]+)$")
_LINE_RE = re.compile(r"^port([0-9]+)/line([0-9]+)$")


@dataclass(frozen=True)
class Route:
    """One electrode pair routed through one chip at one address."""

    pair_index: int  # position in layout.pairs
    chip: int
    address: int
    x_electrode: int  # electrode on pin X<address> ("+")
    y_electrode: int  # electrode on pin Y<address> ("-")


@dataclass(frozen=True)
class Wiring:
    """A checked mux board: chips, their digital lines and one route per pair of S (in layout.pairs order)."""

    chip_names: tuple[str, ...]
    address_lines: tuple[str, str]  # (A, B)
    inhibit_lines: tuple[str, ...]  # one per chip
    routes: tuple[Route, ...]  # routes[p] routes layout.pairs[p]
    pairs: tuple[ElectrodePair, ...]
    source: str = "<memory>"
    layout_path: str | None = None
    electrical: MuxElectrical = MuxElectrical()  # the chips' supply rails and on-resistance

    def __post_init__(self) -> None:
        n_chips = len(self.chip_names)
        if len(self.inhibit_lines) != n_chips:
            raise ConfigError(
                "one inhibit line per chip is needed",
                file=self.source,
                field="chips",
                fix="give every chip an inhibit line",
            )
        if len(self.routes) != len(self.pairs) or any(r.pair_index != p for p, r in enumerate(self.routes)):
            raise ConfigError(
                "routes must list every pair of S once, in layout.pairs order",
                file=self.source,
                field="chips",
                fix="route every pair of the layout exactly once",
            )
        if len(set(self.line_names)) != len(self.line_names):
            raise ConfigError(
                "a digital line is used twice",
                file=self.source,
                field="lines",
                fix="give A, B and every inhibit its own line",
            )
        slots = {(r.chip, r.address) for r in self.routes}
        if len(slots) != len(self.routes) or any(not 0 <= r.chip < n_chips for r in self.routes):
            raise ConfigError(
                "two pairs share one chip address",
                file=self.source,
                field="chips",
                fix="route each pair on its own chip address",
            )

    @property
    def n_chips(self) -> int:
        return len(self.chip_names)

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)

    @cached_property
    def line_names(self) -> tuple[str, ...]:
        """Digital lines in the order of a sequence's columns: A, B, then each chip's inhibit."""
        return (*self.address_lines, *self.inhibit_lines)


# ---- building ---------------------------------------------------------------------------


def sequential_wiring(layout: Layout, lines: tuple[str, ...] | None = None, source: str = "<memory>") -> Wiring:
    """The paper's board for any layout: pair p of S on chip p // 4 at address p % 4, X = pair.i, Y = pair.j.

    `lines` is (A, B, inhibit_0, ...); by default port0/line0, line1, ... in that order.
    """
    pairs = layout.pairs
    n_chips = math.ceil(len(pairs) / ADDRESSES_PER_CHIP)
    lines = lines or tuple(f"port0/line{k}" for k in range(2 + n_chips))
    routes = tuple(
        Route(p, p // ADDRESSES_PER_CHIP, p % ADDRESSES_PER_CHIP, pair.i, pair.j) for p, pair in enumerate(pairs)
    )
    return Wiring(
        tuple(f"U{c + 1}" for c in range(n_chips)),
        (lines[0], lines[1]),
        tuple(lines[2 : 2 + n_chips]),
        routes,
        pairs,
        source=source,
    )


def wiring_to_toml(wiring: Wiring, layout_ref: str | None = None, header: str = "") -> str:
    """The wiring file text for a Wiring (round-trips through load_wiring)."""
    out = [header.rstrip("\n")] if header else []
    if layout_ref:
        out.append(f'layout = "{layout_ref}"')
    e = wiring.electrical
    out += [
        "",
        "[electrical]",
        f"supply_positive_v = {e.supply_positive_v!r}",
        f"supply_negative_v = {e.supply_negative_v!r}",
        f"r_on_ohm = {e.r_on_ohm!r}",
        f"r_on_mismatch_ohm = {e.r_on_mismatch_ohm!r}",
    ]
    out += ["", "[lines]", f'A = "{wiring.address_lines[0]}"', f'B = "{wiring.address_lines[1]}"']
    for c, name in enumerate(wiring.chip_names):
        pins = []
        for r in sorted((r for r in wiring.routes if r.chip == c), key=lambda r: r.address):
            pins += [f"X{r.address} = {r.x_electrode}", f"Y{r.address} = {r.y_electrode}"]
        out += [
            "",
            "[[chips]]",
            f'name = "{name}"',
            f'inhibit = "{wiring.inhibit_lines[c]}"',
            "pins = { " + ", ".join(pins) + " }",
        ]
    return "\n".join(out) + "\n"


# ---- loading ----------------------------------------------------------------------------


def wiring_layout_path(path: str | Path) -> Path | None:
    """The layout a wiring file names (its `layout` key, relative to the file), or None."""
    path = resolve_path(path)
    data = read_toml(path, "wiring file", fix="check the path (protocols/wiring/*.toml)")
    wrong = wrong_kind_problem(WiringFile, data, str(path))  # a layout given as the wiring
    if wrong is not None:
        raise ConfigError(problems=[wrong])
    ref = data.get("layout")
    if ref is None:
        return None
    if not isinstance(ref, str) or not ref:
        raise ConfigError(
            f"'layout' must be a path string, got {ref!r}",
            file=str(path),
            field="layout",
            fix='write layout = "../skins/paper.toml" (relative to the wiring file)',
        )
    target = (path.parent / ref).resolve()
    if not target.is_file():
        raise ConfigError(
            f"the wiring names layout {ref!r}, which is not a file (looked for {target})",
            file=str(path),
            field="layout",
            fix="point layout at the skin file, relative to the wiring file, or pass --layout FILE",
        )
    return target


def load_wiring(path: str | Path, layout: Layout) -> Wiring:
    """Load a wiring file and check it against the layout; every mistake is one Problem in one ConfigError."""
    path = resolve_path(path)
    data = read_toml(path, "wiring file", fix="check the path (protocols/wiring/*.toml)")
    wiring = wiring_from_dict(data, layout, source=str(path))
    return wiring


def wiring_from_dict(data: dict, layout: Layout, source: str = "<memory>") -> Wiring:
    """Build a Wiring from parsed TOML, collecting every problem before raising."""
    problems: list[Problem] = []

    def problem(field: str, message: str, fix: str) -> None:
        problems.append(Problem(message, source, field, fix))

    electrodes = {e.number for e in layout.electrodes}
    pair_index = {(p.i, p.j): k for k, p in enumerate(layout.pairs)}
    line_owner: dict[str, str] = {}

    def line(value: object, field: str) -> str:
        if not isinstance(value, str) or not _LINE_RE.match(value.strip()):
            problem(
                field,
                f"digital line {value!r} is not of the form 'portN/lineM'",
                'write the DAQ line, e.g. "port0/line3"',
            )
            return f"<bad:{field}>"
        value = value.strip()
        if value in line_owner:
            problem(
                field,
                f"digital line '{value}' is already used by {line_owner[value]}",
                "give A, B and every chip's inhibit its own line",
            )
        else:
            line_owner[value] = field
        return value

    tables, schema_problems = parse_tables(WiringFile, data, source)
    problems.extend(schema_problems)
    lines: LinesTable | None = tables.get("lines")
    address_lines = (
        (line(lines.A, "lines.A"), line(lines.B, "lines.B")) if lines else ("<bad:lines.A>", "<bad:lines.B>")
    )
    chips: tuple[ChipEntry, ...] = tables.get("chips") or ()
    n_pairs = len(layout.pairs)
    # a misspelt [[chipz]] is one problem: the chip it held is not also "missing", nor its pairs unrouted
    misspelt = any(p.message.startswith("unknown table") for p in schema_problems)
    if chips and len(chips) * ADDRESSES_PER_CHIP < n_pairs and not misspelt:
        need = math.ceil(n_pairs / ADDRESSES_PER_CHIP)
        problem(
            "chips",
            f"{len(chips)} chips route at most {len(chips) * ADDRESSES_PER_CHIP} pairs, the layout has {n_pairs}",
            f"wire {need} chips ({need - len(chips)} more)",
        )

    names: list[str] = []
    inhibits: list[str] = []
    routed: dict[int, tuple[int, int, str]] = {}  # pair index -> (chip, address, field)
    routes: list[Route] = []
    bad_pins = False  # a pin already reported: its address and the pairs left unrouted are not new mistakes
    twice: list[int] = []  # indices in problems of the "routed twice" problems
    for c, chip in enumerate(chips):
        where = f"chips[{c}]"
        name = chip.name or f"U{c + 1}"
        if name in names:
            problem(f"{where}.name", f"chip name '{name}' is used twice", "give every chip its own name")
        names.append(name)
        inhibits.append(line(chip.inhibit, f"{where}.inhibit"))
        pins = chip.pins
        on_pin: dict[tuple[str, int], int] = {}
        bad_addresses: set[int] = set()
        for pin, value in pins.items():
            field = f"{where}.pins.{pin}"
            m = _PIN_RE.match(pin)
            if not m or not 0 <= int(m.group(2)) < ADDRESSES_PER_CHIP:
                bad_pins = True
                meant = _PIN_RE.match(pin.upper().replace("O", "0"))
                if meant and 0 <= int(meant.group(2)) < ADDRESSES_PER_CHIP:
                    bad_addresses.add(int(meant.group(2)))
                    hint = f"did you mean '{meant.group(0)}'? "
                else:
                    bad_addresses.update(range(ADDRESSES_PER_CHIP))
                    hint = ""
                problem(
                    field,
                    f"chip '{name}' has no pin '{pin}'",
                    f"{hint}use X0..X{ADDRESSES_PER_CHIP - 1} and Y0..Y{ADDRESSES_PER_CHIP - 1}",
                )
                continue
            address = int(m.group(2))
            if isinstance(value, list):
                if len(value) > 1:
                    problem(
                        field,
                        f"two electrodes on one pin: {pin} of chip '{name}' is wired to electrodes "
                        f"{', '.join(map(str, value))}",
                        f"wire exactly one electrode to {pin}",
                    )
                    bad_pins = True
                    bad_addresses.add(address)
                    continue
                value = value[0] if value else None
            if isinstance(value, bool) or not isinstance(value, int):
                problem(
                    field,
                    f"pin {pin} of chip '{name}' must name an electrode number, got {value!r}",
                    f"write {pin} = <electrode number>",
                )
                bad_pins = True
                bad_addresses.add(address)
                continue
            if value not in electrodes:
                problem(
                    field,
                    f"electrode {value} on pin {pin} of chip '{name}' is not in the layout "
                    f"(electrodes {', '.join(map(str, sorted(electrodes)))})",
                    "use an electrode number of the layout",
                )
                bad_pins = True
                bad_addresses.add(address)
                continue
            on_pin[(m.group(1), int(m.group(2)))] = value
        for k in range(ADDRESSES_PER_CHIP):
            x, y = on_pin.get(("X", k)), on_pin.get(("Y", k))
            if (x is None and y is None) or k in bad_addresses:
                continue
            field = f"{where}.pins.X{k}/Y{k}"
            if x is None or y is None:
                wired, missing = ("X", "Y") if y is None else ("Y", "X")
                problem(
                    field,
                    f"address {k} of chip '{name}' has {wired}{k} wired but not {missing}{k}",
                    f"wire {missing}{k} to the pair's other electrode, or free {wired}{k}",
                )
                continue
            if x == y:
                problem(
                    field,
                    f"pair with both ends on electrode {x}: X{k} and Y{k} of chip '{name}' are on the same electrode",
                    f"wire X{k} and Y{k} to the two different electrodes of a pair",
                )
                bad_pins = True  # the pair that belongs here is the one left unrouted: not a second mistake
                continue
            key = (min(x, y), max(x, y))
            p = pair_index[key]
            if p in routed:
                oc, ok, ofield = routed[p]
                twice.append(len(problems))
                problem(
                    field,
                    f"pair {key[0]}-{key[1]} is routed twice: chip '{name}' address {k} and {ofield}",
                    "route every pair once: free one of the two addresses",
                )
                continue
            routed[p] = (c, k, field)
            routes.append(Route(p, c, k, x, y))
    unrouted = [pair for p, pair in enumerate(layout.pairs) if p not in routed]
    if twice and unrouted:
        # a pair wired twice usually stands where an unrouted pair belongs: one mistake, one problem
        first = problems[twice[0]]
        labels = ", ".join(pair.label for pair in unrouted)
        problems[twice[0]] = Problem(
            first.message, first.file, first.field, f"{first.fix}; pairs not routed by any chip: {labels}"
        )
    elif chips and len(chips) * ADDRESSES_PER_CHIP >= n_pairs and not bad_pins and not misspelt:
        for pair in unrouted:
            problem(
                "chips",
                f"pair {pair.label} of S is not routed by any chip",
                f"wire electrodes {pair.i} and {pair.j} to Xk and Yk of a free chip address",
            )
    raise_problems(problems)
    return Wiring(
        tuple(names),
        address_lines,
        tuple(inhibits),
        tuple(sorted(routes, key=lambda r: r.pair_index)),
        layout.pairs,
        source=source,
        layout_path=tables.get("layout"),
        electrical=tables.get("electrical") or MuxElectrical(),
    )

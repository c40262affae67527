"""One press from the command line, shared by `neatskin skin press` and `neatskin skin netlist`: its options, their
checks, the pinches a user adds (`--pinch CHANNEL=RATIO`), and the channel and pair resistances of the model."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from typing import TYPE_CHECKING

from neatskin.errors import ConfigError

if TYPE_CHECKING:  # `neatskin --help` loads this module: numpy and the layout only when a press is evaluated
    import numpy as np

    from neatskin.layout import Layout

DEFAULT_LAYOUT = "protocols/skins/paper.toml"
PAPER_DEPTH_MM = 3.5


def add_press_arguments(parser: argparse.ArgumentParser, position_required: bool) -> None:
    """--layout, the press (--x-mm, --y-mm, --depth-mm, --probe-radius-mm), the model (--fidelity, --deformation) and
    --pinch. Without position_required, no position means no press (the skin at rest, pinches apart)."""
    parser.add_argument("--layout", default=DEFAULT_LAYOUT, help=f"skin layout TOML (default {DEFAULT_LAYOUT})")
    rest = "" if position_required else " (with --y-mm; leave both out for the skin at rest)"
    parser.add_argument("--x-mm", type=float, required=position_required, help="press centre, sensor frame" + rest)
    parser.add_argument("--y-mm", type=float, required=position_required, help="press centre, sensor frame" + rest)
    parser.add_argument(
        "--depth-mm", type=float, default=None, help=f"press depth (default and paper: {PAPER_DEPTH_MM:g} mm)"
    )
    parser.add_argument("--probe-radius-mm", type=float, default=2.75, help="flat probe radius (paper: 2.75 mm)")
    parser.add_argument(
        "--fidelity", choices=("deformation", "network"), default="deformation", help="skin model (default deformation)"
    )
    parser.add_argument(
        "--deformation",
        choices=("parametric", "fe-kernel"),
        default="parametric",
        help="the pinch: the parametric profile (default) or the finite-element kernel of this layout (packaged for "
        "the paper skin, else computed once and cached)",
    )
    parser.add_argument(
        "--pinch",
        action="append",
        default=[],
        metavar="CHANNEL=RATIO",
        help="after the press, multiply a channel's resistance by RATIO (> 0; inf shuts it); CHANNEL is its name "
        "(e.g. J00-J10) or its index from 0; repeat for more channels",
    )


@dataclass(frozen=True)
class PressResult:
    """One press evaluated: the channels' resistances at rest and pressed (pinches applied), (channels,), and the
    pairs' R_eq from them, (pairs,), in ohm; inf for a shut channel or a pair cut apart."""

    layout: Layout
    description: str
    channel_rest_ohm: np.ndarray
    channel_ohm: np.ndarray
    pair_rest_ohm: np.ndarray
    pair_ohm: np.ndarray
    force_n: float


def evaluate_press(args: argparse.Namespace) -> PressResult:
    """The press the options describe, checked before any work (one ConfigError naming the option and the fix)."""
    import numpy as np

    from neatskin.layout import load_layout
    from neatskin.skin.model import SkinModel
    from neatskin.skin.network import equivalent_resistance

    pressed = args.x_mm is not None or args.y_mm is not None
    if pressed and (args.x_mm is None or args.y_mm is None):
        raise ConfigError(
            "a press needs both --x-mm and --y-mm", field="--x-mm/--y-mm", fix="give both, or neither for no press"
        )
    if not pressed and args.depth_mm not in (None, 0):
        raise ConfigError(
            f"--depth-mm {args.depth_mm:g} without a position", field="--depth-mm", fix="give --x-mm and --y-mm too"
        )
    x, y = (args.x_mm, args.y_mm) if pressed else (0.0, 0.0)
    depth = (PAPER_DEPTH_MM if args.depth_mm is None else args.depth_mm) if pressed else 0.0
    for flag, value in (
        ("--x-mm", x),
        ("--y-mm", y),
        ("--depth-mm", depth),
        ("--probe-radius-mm", args.probe_radius_mm),
    ):
        positive = flag == "--probe-radius-mm"
        if not math.isfinite(value) or (positive and value <= 0):
            raise ConfigError(
                f"{flag} must be a finite number{' > 0' if positive else ''}, got {value}",
                field=flag,
                fix=f"pass a valid {flag}",
            )
    layout = load_layout(args.layout)
    pinches = parse_pinches(layout, args.pinch)
    if pressed:
        check_press_on_skin(layout, x, y, depth, args.probe_radius_mm)
    kernel = None
    if args.deformation == "fe-kernel":
        from neatskin.skin.kernel import KernelSpec, load_kernel, solve_notice

        spec = KernelSpec.for_layout(layout, args.probe_radius_mm)
        try:
            kernel = load_kernel(spec, compute=False)
        except FileNotFoundError:  # no kernel packaged or cached for this probe: say why nothing comes for minutes
            print(f"neatskin: {solve_notice()}", file=sys.stderr, flush=True)
            kernel = load_kernel(spec)
    model = SkinModel(layout, fidelity=args.fidelity, probe_radius_mm=args.probe_radius_mm, kernel=kernel)
    rest = model.channel_resistance_ohm(0.0, 0.0, 0.0)[0]
    channel = model.channel_resistance_ohm(x, y, depth)[0]
    for c, ratio in pinches.items():
        channel[c] *= ratio
    with np.errstate(divide="ignore"):  # one solve each, as SkinModel.pair_resistance_ohm does: the same bits
        pair_rest, pair = (equivalent_resistance(layout, 1.0 / r) for r in (rest, channel))
    force = float(model.contact_force_n(depth)[0])
    where = f"press at ({x:g}, {y:g}) mm, depth {depth:g} mm, force {force:.2f} N" if pressed else "no press"
    pinched = "".join(f", {layout.channels[c].name} pinched x {ratio!r}" for c, ratio in pinches.items())
    description = f"{where}, {args.fidelity} model, {model.deformation} pinch{pinched}, layout {layout.name}"
    return PressResult(layout, description, rest, channel, pair_rest, pair, force)


def parse_pinches(layout: Layout, specs: list[str]) -> dict[int, float]:
    """--pinch CHANNEL=RATIO values -> {channel index: ratio}; every bad one in one ConfigError."""
    names = {c.name: k for k, c in enumerate(layout.channels)}
    out: dict[int, float] = {}
    problems = []
    for spec in specs:
        channel, sep, ratio_text = spec.rpartition("=")
        index = names.get(channel)
        if index is None and channel.isdigit() and int(channel) < layout.n_channels:
            index = int(channel)
        try:
            ratio = float(ratio_text)
        except ValueError:
            ratio = math.nan
        if not sep or index is None:
            problems.append(
                f"--pinch {spec!r}: no channel {channel!r} in layout {layout.name} (its channels: "
                f"{', '.join(names)}, or an index 0 to {layout.n_channels - 1})"
            )
        elif ratio == 0 and _written(ratio_text) > 0:
            problems.append(f"--pinch {spec!r}: the ratio underflows to 0 (floats reach down to about 1e-308)")
        elif not ratio > 0:
            problems.append(f"--pinch {spec!r}: the ratio must be a number > 0 (inf shuts the channel)")
        elif math.isinf(ratio) and _written(ratio_text).is_finite():
            problems.append(
                f"--pinch {spec!r}: the ratio overflows (floats reach up to about 1e308); write inf to shut the channel"
            )
        elif index in out:
            problems.append(f"--pinch {spec!r}: channel {layout.channels[index].name} is pinched twice")
        else:
            out[index] = ratio
    if problems:
        raise ConfigError("; ".join(problems), field="--pinch", fix="give --pinch CHANNEL=RATIO, e.g. J00-J10=1e12")
    return out


def _written(text: str) -> Decimal:
    """A number as typed, without float's overflow or underflow (NaN when it is none)."""
    try:
        return Decimal(text.strip())
    except InvalidOperation:
        return Decimal("NaN")


def check_press_on_skin(layout: Layout, x_mm: float, y_mm: float, depth_mm: float, probe_radius_mm: float) -> None:
    """A press the skin cannot take is refused, as a protocol's would be, not answered with plausible numbers: a
    depth above the surface or through the skin, or a probe that misses the channel grid (every dR 0)."""
    thickness = layout.thickness_mm
    if not 0 <= depth_mm < thickness:
        raise ConfigError(
            f"--depth-mm {depth_mm:g} is {'above the surface' if depth_mm < 0 else 'through the skin'} "
            f"(the skin of {layout.name} is {thickness:g} mm thick)",
            field="--depth-mm",
            fix=f"pass a depth from 0 (no press) to below {thickness:g} mm (the paper pressed 3.5 mm)",
        )
    x0, y0, x1, y1 = layout.bounds_mm
    r = probe_radius_mm
    if not (x0 - r < x_mm < x1 + r and y0 - r < y_mm < y1 + r):
        raise ConfigError(
            f"a probe of radius {r:g} mm at ({x_mm:g}, {y_mm:g}) mm misses the skin's channels "
            f"(x {x0:g} to {x1:g}, y {y0:g} to {y1:g} mm): every dR would be 0",
            field="--x-mm/--y-mm",
            fix=f"press within x {x0:g} to {x1:g} and y {y0:g} to {y1:g} mm (the sensor frame)",
        )

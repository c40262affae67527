"""The `neatskin mux` commands: the switching table a technician checks the board against with a meter."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from neatskin.tomlfile import resolve_path

DEFAULT_WIRING = Path("protocols") / "wiring" / "paper.toml"


def register(subparsers) -> None:
    mux = subparsers.add_parser(
        "mux",
        help="mux board: the switching table to check the wiring against",
        description="The mux board: the switching table (chip, address, line states and windows per pair) a "
        "technician checks the board against with a meter.",
    )
    sub = mux.add_subparsers(dest="mux_command", metavar="COMMAND", required=True)
    table = sub.add_parser("table", help="print, for each pair in sweep order, chip, address, line states and windows")
    table.add_argument("wiring", nargs="?", type=Path, default=None, help=f"wiring file (default: {DEFAULT_WIRING})")
    table.add_argument(
        "--layout", type=Path, default=None, help="skin layout (default: the wiring file's `layout` key)"
    )
    table.add_argument(
        "--protocol",
        type=Path,
        default=None,
        help="campaign protocol: take the wiring, rate, settle/live samples and hold from it",
    )
    table.add_argument("--rate-hz", type=float, default=None, help="sample clock (default 10000)")
    table.add_argument("--live-samples", type=int, default=None, help="measured samples per pair (default 100)")
    table.add_argument("--settle-samples", type=int, default=None, help="discarded samples per pair (default 20)")
    table.add_argument("--hold-s", type=float, default=None, help="press hold: say how many whole sweeps fit in it")
    table.add_argument("--break-samples", type=int, default=2, help="all-inhibited samples per switch (default 2)")
    table.add_argument(
        "--order",
        choices=("pairs", "gray"),
        default="pairs",
        help="visiting order: layout order, or Gray-coded addresses (fewer line edges)",
    )
    table.set_defaults(handler=table_handler)


def table_handler(args: argparse.Namespace) -> int:
    settings: dict[str, Any] = {
        "rate_hz": 10_000.0,
        "live_samples": 100,
        "settle_samples": 20,
        "hold_s": None,
        "wiring": None,
    }
    if args.protocol is not None:
        settings.update(protocol_settings(args.protocol))
    for key in ("rate_hz", "live_samples", "settle_samples", "hold_s", "wiring"):
        if getattr(args, key) is not None:  # the command line wins over the protocol
            settings[key] = getattr(args, key)
    print(
        mux_table(
            settings["wiring"],
            args.layout,
            settings["rate_hz"],
            settings["live_samples"],
            settings["settle_samples"],
            args.break_samples,
            args.order,
            settings["hold_s"],
        ),
        end="",
    )
    return 0


def protocol_settings(path: Path) -> dict:
    """The few protocol keys the table needs ([files].wiring, [acquisition], [press].hold_s), each checked
    against the protocol schema; other sections are left to the campaign loader (acquisition does not import rig)."""
    from neatskin.config import parse_partial
    from neatskin.config.files import AcquisitionSettings, FilesTable, PressSpec
    from neatskin.errors import ConfigError
    from neatskin.tomlfile import read_toml

    path = resolve_path(path)
    data = read_toml(path, "protocol", fix="check the path")
    out: dict = {}
    problems = []
    wanted = (
        ("files", FilesTable, ("wiring",)),
        ("acquisition", AcquisitionSettings, ("rate_hz", "live_samples", "settle_samples")),
        ("press", PressSpec, ("hold_s",)),
    )
    for table, schema, keys in wanted:
        if table not in data:
            continue
        values, found = parse_partial(schema, data[table], str(path), table)
        problems += found
        out.update({key: values[key] for key in keys if key in values})
    if problems:
        raise ConfigError(problems=problems)
    if "wiring" in out:
        out["wiring"] = Path(path).parent / out["wiring"]
    return out


def mux_table(
    wiring_path: Path | None = None,
    layout_path: Path | None = None,
    rate_hz: float = 10_000.0,
    live_samples: int = 100,
    settle_samples: int = 20,
    break_samples: int = 2,
    order: str = "pairs",
    hold_s: float | None = None,
) -> str:
    """The table as text (the CLI prints it)."""
    from neatskin.acquisition.sequence import SweepTiming, build_sweep, check_sweep
    from neatskin.acquisition.wiring import load_wiring, wiring_layout_path
    from neatskin.errors import ConfigError
    from neatskin.layout import load_layout

    wiring_path = wiring_path or resolve_path(DEFAULT_WIRING)
    layout_path = layout_path or wiring_layout_path(wiring_path)
    if layout_path is None:
        raise ConfigError(
            "the wiring file names no layout",
            file=str(wiring_path),
            field="layout",
            fix='add layout = "../skins/<skin>.toml" to it, or pass --layout FILE',
        )
    layout = load_layout(layout_path)
    wiring = load_wiring(wiring_path, layout)
    timing = SweepTiming(rate_hz, settle_samples, live_samples, break_samples)
    sweep = build_sweep(wiring, timing, order)
    issues = check_sweep(sweep)
    if issues:  # cannot happen for a sequence built here; a guard for edits to the builder
        raise ConfigError("; ".join(issues), file=str(wiring_path), fix="report this as a bug")
    inhibit_names = [f"{name}.INH" for name in wiring.chip_names]
    out = [
        f"wiring {wiring_path} (layout {layout.name}: {layout.n_electrodes} electrodes, {wiring.n_pairs} pairs, "
        f"{wiring.n_chips} chips)",
        "lines: " + ", ".join(f"{label}={line}" for label, line in zip(["A", "B", *inhibit_names], wiring.line_names)),
        "line states while the pair is live: A B then each chip's inhibit (1 = inhibited); "
        "every switch first inhibits all chips for "
        f"{break_samples} samples and changes A/B halfway",
        "",
    ]
    header = (
        f"{'step':>4} {'pair':>5} {'chip':>4} {'addr':>4} {'X':>2} {'Y':>2}  {'A B INH':<{4 + 2 * wiring.n_chips}}"
        f" {'settle (discarded)':>18} {'live (measured)':>16} {'live at ms':>10}"
    )
    out.append(header)
    for step, p in enumerate(sweep.order):
        route = wiring.routes[p]
        row = sweep.lines[sweep.live_windows[p, 0]]
        bits = " ".join("1" if b else "0" for b in row)
        s0, s1 = sweep.settle_windows[p]
        l0, l1 = sweep.live_windows[p]
        out.append(
            f"{step:>4} {layout.pairs[p].label:>5} {wiring.chip_names[route.chip]:>4} {route.address:>4} "
            f"{route.x_electrode:>2} {route.y_electrode:>2}  {bits:<{4 + 2 * wiring.n_chips}} "
            f"{f'[{s0}, {s1})':>18} {f'[{l0}, {l1})':>16} {1e3 * l0 / rate_hz:>10.1f}"
        )
    out += [
        "",
        f"sweep: {sweep.n_samples} samples = {sweep.duration_s * 1e3:.1f} ms at {rate_hz:g} Hz "
        f"({wiring.n_pairs} x ({break_samples} break + {settle_samples} settle + {live_samples} live)); "
        f"{sweep.line_transitions()} line edges per sweep ({order} order)",
    ]
    if hold_s is not None:
        # live windows of one pair recur every sweep; at least floor((hold - live) / sweep) lie wholly inside
        # any hold of that length, whatever the sweep's phase against the press
        live_s = live_samples / rate_hz
        times = max(0, int((hold_s - live_s) // sweep.duration_s))
        out.append(
            f"a {hold_s:g} s hold: every pair is measured at least {times} time{'s' if times != 1 else ''} "
            "inside it, whatever the sweep's phase" + ("  <- too short for a pressed value" if times < 1 else "")
        )
    return "\n".join(out) + "\n"

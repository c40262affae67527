"""The `neatskin mux` commands: the switching table a technician checks the board against with a meter."""

from __future__ import annotations

import argparse
from pathlib import Path

import neatskin

DEFAULT_WIRING = Path("protocols") / "wiring" / "paper.toml"


def _repo_default(relative: Path) -> Path:
    """A path relative to the working directory, else to the repository holding the package."""
    if relative.exists():
        return relative
    return Path(neatskin.__file__).resolve().parent.parent / relative


def register(subparsers) -> None:
    mux = subparsers.add_parser("mux", help="mux board: wiring checks and the switching table")
    sub = mux.add_subparsers(dest="mux_command", metavar="COMMAND", required=True)
    table = sub.add_parser("table", help="print, for each pair in sweep order, chip, address, line states and windows")
    table.add_argument("wiring", nargs="?", type=Path, default=None,
                       help=f"wiring file (default: {DEFAULT_WIRING})")
    table.add_argument("--layout", type=Path, default=None,
                       help="skin layout (default: the wiring file's `layout` key)")
    table.add_argument("--rate-hz", type=float, default=10_000.0, help="sample clock (default 10000)")
    table.add_argument("--live-samples", type=int, default=100, help="measured samples per pair (default 100)")
    table.add_argument("--settle-samples", type=int, default=20, help="discarded samples per pair (default 20)")
    table.add_argument("--break-samples", type=int, default=2, help="all-inhibited samples per switch (default 2)")
    table.add_argument("--order", choices=("pairs", "gray"), default="pairs",
                       help="visiting order: layout order, or Gray-coded addresses (fewer line edges)")
    table.set_defaults(handler=table_handler)


def table_handler(args: argparse.Namespace) -> int:
    print(mux_table(args.wiring, args.layout, args.rate_hz, args.live_samples, args.settle_samples,
                    args.break_samples, args.order), end="")
    return 0


def mux_table(wiring_path: Path | None = None, layout_path: Path | None = None, rate_hz: float = 10_000.0,
              live_samples: int = 100, settle_samples: int = 20, break_samples: int = 2, order: str = "pairs") -> str:
    """The table as text (the CLI prints it)."""
    from neatskin.errors import ConfigError
    from neatskin.layout import load_layout
    from neatskin.acquisition.sequence import SweepTiming, build_sweep, check_sweep
    from neatskin.acquisition.wiring import load_wiring, wiring_layout_path

    wiring_path = wiring_path or _repo_default(DEFAULT_WIRING)
    layout_path = layout_path or wiring_layout_path(wiring_path)
    if layout_path is None:
        raise ConfigError("the wiring file names no layout", file=str(wiring_path), field="layout",
                          fix='add layout = "../skins/<skin>.toml" to it, or pass --layout FILE')
    layout = load_layout(layout_path)
    wiring = load_wiring(wiring_path, layout)
    timing = SweepTiming(rate_hz, settle_samples, live_samples, break_samples)
    sweep = build_sweep(wiring, timing, order)
    issues = check_sweep(sweep)
    if issues:  # cannot happen for a sequence built here; a guard for edits to the builder
        raise ConfigError("; ".join(issues), file=str(wiring_path), fix="report this as a bug")
    inhibit_names = [f"{name}.INH" for name in wiring.chip_names]
    out = [f"wiring {wiring_path} (layout {layout.name}: {layout.n_electrodes} electrodes, {wiring.n_pairs} pairs, "
           f"{wiring.n_chips} chips)",
           "lines: " + ", ".join(f"{label}={line}" for label, line in
                                 zip(["A", "B", *inhibit_names], wiring.line_names)),
           "line states while the pair is live: A B then each chip's inhibit (1 = inhibited); "
           "every switch first inhibits all chips for "
           f"{break_samples} samples and changes A/B halfway",
           ""]
    header = f"{'step':>4} {'pair':>5} {'chip':>4} {'addr':>4} {'X':>2} {'Y':>2}  {'A B INH':<{4 + 2 * wiring.n_chips}}" \
             f" {'settle (discarded)':>18} {'live (measured)':>16} {'live at ms':>10}"
    out.append(header)
    for step, p in enumerate(sweep.order):
        route = wiring.routes[p]
        row = sweep.lines[sweep.live_windows[p, 0]]
        bits = " ".join("1" if b else "0" for b in row)
        s0, s1 = sweep.settle_windows[p]
        l0, l1 = sweep.live_windows[p]
        out.append(f"{step:>4} {layout.pairs[p].label:>5} {wiring.chip_names[route.chip]:>4} {route.address:>4} "
                   f"{route.x_electrode:>2} {route.y_electrode:>2}  {bits:<{4 + 2 * wiring.n_chips}} "
                   f"{f'[{s0}, {s1})':>18} {f'[{l0}, {l1})':>16} {1e3 * l0 / rate_hz:>10.1f}")
    out += ["", f"sweep: {sweep.n_samples} samples = {sweep.duration_s * 1e3:.1f} ms at {rate_hz:g} Hz "
            f"({wiring.n_pairs} x ({break_samples} break + {settle_samples} settle + {live_samples} live)); "
            f"{sweep.line_transitions()} line edges per sweep ({order} order)"]
    return "\n".join(out) + "\n"

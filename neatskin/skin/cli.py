"""The `neatskin skin` command group: sensitivity maps of a skin layout as PNG and parquet, one press, and the fit."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from neatskin.cligroups import add_out, add_quiet
from neatskin.skin.clipress import DEFAULT_LAYOUT, add_press_arguments, evaluate_press


def register(subparsers) -> None:
    skin = subparsers.add_parser(
        "skin",
        help="the sensor's physics: sensitivity maps, one press's R_eq, fit to a campaign, finite-element pinch",
        description="The simulated skin (network solver, deformation model, finite-element pinch): sensitivity maps, "
        "one press's R_eq, fitting the model to a recorded campaign, and the mechanics of a press.",
    )
    commands = skin.add_subparsers(dest="skin_command", metavar="SKIN_COMMAND", required=True)
    maps = commands.add_parser(
        "maps",
        help="sensitivity maps (paper Fig. 3 and 5, and the dense deformation-model maps)",
        description="Write the paper's simulated sensitivity maps (each channel +50 % in turn) and the same "
        "maps from the deformation model on a dense grid of presses, as PNG and parquet.",
    )
    maps.add_argument("--layout", default=DEFAULT_LAYOUT, help=f"skin layout TOML (default {DEFAULT_LAYOUT})")
    add_out(maps, "output folder (created; default out/skin-maps)", default=Path("out/skin-maps"))
    maps.add_argument("--grid-step-mm", type=float, default=0.25, help="press grid step for the dense maps")
    maps.add_argument("--depth-mm", type=float, default=3.5, help="press depth (paper: 3.5 mm)")
    maps.add_argument("--probe-radius-mm", type=float, default=2.75, help="flat probe radius (paper: 2.75 mm)")
    maps.add_argument(
        "--fidelity", choices=("deformation", "network"), default="deformation", help="skin model for the dense maps"
    )
    add_quiet(maps)
    maps.set_defaults(handler=maps_handler)
    press = commands.add_parser(
        "press",
        help="R_eq of every pair for one press (baseline, pressed, change)",
        description="Print the baseline, pressed and changed R_eq of every electrode pair for one press.",
    )
    add_press_arguments(press, position_required=True)
    digits = press.add_mutually_exclusive_group()
    digits.add_argument(
        "--digits", type=_decimals, default=3, metavar="N", help="decimals of the resistances (default 3)"
    )
    digits.add_argument(
        "--exact",
        action="store_true",
        help="every resistance as its full double (repr: the shortest decimal that reads back exactly)",
    )
    press.add_argument("--channels", action="store_true", help="also print every channel's resistance")
    press.set_defaults(handler=press_handler)
    netlist = commands.add_parser(
        "netlist",
        help="a SPICE netlist of one press's channel network, with neatskin's R_eq, to check against ngspice",
        description="Write a SPICE netlist of the channel network for one press (or none): one copy per electrode "
        "pair, 1 A into one electrode and the other grounded, every channel's resistance as its full double, and "
        "neatskin's R_eq of every pair beside it. `ngspice -b FILE` solves it and prints both with their relative "
        "difference (docs/skin.md).",
    )
    add_press_arguments(netlist, position_required=False)
    add_out(netlist, "netlist file to write (default: standard output)")
    netlist.set_defaults(handler=netlist_handler)
    fit = commands.add_parser(
        "fit",
        help="fit the skin model to a recorded campaign (channel baselines, pinch, placement, noise, drift)",
        description="Estimate the skin model's parameters from a recorded campaign by nonlinear least squares "
        "through the forward model, with 95 % intervals and the pinch's correlation, and write a skin profile. "
        "The fit's pinch is the parametric one: it cannot describe a dry run of the paper-like scene, whose skin "
        "presses the finite-element pinch kernel (channels shut under the probe), so on such a campaign its values "
        "and intervals describe the parametric model's best compromise, not the skin (the command warns when the "
        "manifest says so; docs/skin.md, 'Fitting a skin to a recorded campaign').",
    )
    fit.add_argument("campaign", metavar="CAMPAIGN_DIR", help="a finished campaign folder (presses.parquet)")
    add_out(fit, "skin profile TOML to write (default CAMPAIGN_DIR/skin_profile.toml)")
    fit.add_argument("--probe-radius-mm", type=float, default=2.75, help="flat probe radius (paper: 2.75 mm)")
    fit.set_defaults(handler=fit_handler)
    mech = commands.add_parser(
        "mechanics",
        help="finite-element press across a channel: the pinch kernel (A/A0 against offset and depth) and the force",
        description="Solve the press with scikit-fem (plane strain across one channel, nearly incompressible "
        "neo-Hookean, large deformation) at every probe offset, and the intact skin under the strip and the round "
        "probe (axisymmetric); carry the channel kernel onto the round probe (quasi-3D) and write "
        "pinch_kernel.parquet and pinch_kernel.png.",
    )
    mech.add_argument("--layout", default=DEFAULT_LAYOUT, help=f"skin layout TOML (default {DEFAULT_LAYOUT})")
    add_out(mech, "output folder (created; default out/skin-mechanics)", default="out/skin-mechanics")
    mech.add_argument("--probe-radius-mm", type=float, default=2.75, help="flat probe radius (paper: 2.75 mm)")
    mech.add_argument("--element-mm", type=float, default=0.5, help="element size at the channel and the probe")
    mech.add_argument("--max-offset-mm", type=float, default=10.0, help="largest probe offset (step 0.5 mm)")
    mech.add_argument("--jobs", type=int, default=2, help="worker processes (one offset each)")
    mech.set_defaults(handler=mechanics_handler)


def mechanics_handler(args: argparse.Namespace) -> int:
    import time

    import numpy as np
    from tqdm import tqdm

    from neatskin.errors import ConfigError
    from neatskin.layout import load_layout
    from neatskin.skin.kernel import KernelSpec, compute_kernel, write_kernel
    from neatskin.skin.mechanics import SolverSettings
    from neatskin.skin.plots import plot_kernel

    for name in ("probe_radius_mm", "element_mm", "max_offset_mm"):
        value = getattr(args, name)
        if not (np.isfinite(value) and value > 0):
            flag = "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} must be a number > 0, got {value}", field=flag, fix=f"pass a positive {flag}")
    layout = load_layout(args.layout)
    offsets = tuple(np.round(np.arange(0.0, args.max_offset_mm + 1e-9, 0.5), 6))
    try:
        spec = KernelSpec.for_layout(
            layout, args.probe_radius_mm, settings=SolverSettings(element_mm=args.element_mm), offsets_mm=offsets
        )
    except ValueError as exc:
        raise ConfigError(str(exc), field="layout", fix="give the channels one cross-section") from exc
    out = Path(args.out)
    t0 = time.perf_counter()
    with tqdm(total=len(offsets) + 2, desc="FE press", unit="solve") as bar:
        kernel = compute_kernel(spec, n_jobs=max(1, args.jobs), progress=bar.update)
    elapsed = time.perf_counter() - t0
    data = write_kernel(kernel, out / "pinch_kernel.parquet")
    g = spec.geometry
    title = (
        f"{layout.name}: {g.thickness_mm:g} mm skin, {g.channel_width_mm:g} x {g.channel_height_mm:g} mm channel "
        f"{g.channel_depth_mm:g} mm deep, {2 * g.probe_radius_mm:g} mm flat bonded probe, mu "
        f"{spec.material.shear_modulus_mpa * 1e3:g} kPa; quasi-3D, {args.element_mm:g} mm elements"
    )
    plot = plot_kernel(kernel, out / "pinch_kernel.png", title)
    print(f"kernel {kernel.key}: {len(offsets)} offsets x {kernel.depths_mm.size} depths in {elapsed:.0f} s")
    print(data)
    print(plot)
    return 0


def fit_handler(args: argparse.Namespace) -> int:
    import time

    from neatskin.campaignread import read_manifest
    from neatskin.errors import NeatskinError
    from neatskin.skin.fit import fit_skin, model_mismatch_warning

    manifest = None
    try:  # read once: the warning is said first, so a fit the campaign cannot support still shows why its model
        # was the wrong one, and the fit takes the same manifest
        manifest = read_manifest(args.campaign)
    except NeatskinError:  # no readable manifest: fit_skin reads it again and names the problem
        pass
    warning = model_mismatch_warning(manifest) if manifest is not None else None
    if warning:
        print(f"warning: {warning}")
    t0 = time.perf_counter()
    result = fit_skin(args.campaign, probe_radius_mm=args.probe_radius_mm, manifest=manifest)
    out = Path(args.out) if args.out else Path(args.campaign) / "skin_profile.toml"
    out.write_text(result.to_toml())
    print(f"skin fitted to {args.campaign} in {time.perf_counter() - t0:.1f} s (95 % intervals)")
    for name in ("pinch_gain", "decay_ratio", "placement_error_mm", "noise_ohm", "drift_per_h"):
        v = getattr(result, name)
        print(f"  {name:<20s} {v.value:12.5g}   [{v.ci95[0]:.5g}, {v.ci95[1]:.5g}]{v.coverage_text()}")
    print(f"  correlation(pinch_gain, decay_ratio) = {result.pinch_correlation:+.2f}")
    print(f"  rms residual of the mean dR per position: {result.rms_residual_ohm:.3g} ohm")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"wrote {out}")
    return 0


def press_handler(args: argparse.Namespace) -> int:
    press = evaluate_press(args)

    def text(value: float) -> str:
        return repr(value) if args.exact else f"{value:.{args.digits}f}"

    rows: list[tuple[str, ...]] = [
        (pair.label, text(r0), text(r), text(r - r0), f"{100 * (r / r0 - 1):.3f}")
        for pair, r0, r in zip(press.layout.pairs, press.pair_rest_ohm.tolist(), press.pair_ohm.tolist())
    ]
    print(press.description)
    _table(("pair", "R0_ohm", "R_ohm", "dR_ohm", "dR_pct"), rows)
    if args.channels:
        rows = [
            (f"c{c} {channel.name}", text(r0), text(r), repr(r / r0) if args.exact else f"{r / r0:.6g}")
            for c, (channel, r0, r) in enumerate(
                zip(press.layout.channels, press.channel_rest_ohm.tolist(), press.channel_ohm.tolist())
            )
        ]
        _table(("channel", "R0_ohm", "R_ohm", "R/R0"), rows)
    return 0


def _table(header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> None:
    """Right-aligned columns at least 12 wide (the pairs' table of old: 6, then 12s, 8), wider for longer values."""
    widths = [max(len(h), *(len(row[k]) for row in rows)) for k, h in enumerate(header)]
    widths = [max(w, 6 if k == 0 else 8 if k == len(header) - 1 else 12) for k, w in enumerate(widths)]
    for row in (header, *rows):
        print(" ".join(f"{cell:>{w}s}" for cell, w in zip(row, widths)))


def _decimals(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 17:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of decimals from 0 to 17 (or use --exact)")
    return value


def netlist_handler(args: argparse.Namespace) -> int:
    import sys

    from neatskin import __version__
    from neatskin.skin.netlist import spice_netlist

    press = evaluate_press(args)
    netlist = spice_netlist(
        press.layout,
        press.channel_ohm,
        press.pair_ohm,
        title=f"neatskin skin netlist: {press.description}",
        notes=[f"written by neatskin {__version__}; check it with: ngspice -b FILE"],
    )
    if args.out is None:
        sys.stdout.write(netlist.text)
        return 0
    try:
        Path(args.out).write_text(netlist.text)
    except OSError as exc:  # a full disk fails at the close, with no file name on the exception: name it here
        from neatskin.oserrors import os_error

        raise os_error(exc, "write", args.out, then="then run it again") from exc
    print(f"wrote {args.out}: {press.description}")
    print("neatskin R_eq (repr), to compare with `ngspice -b` (its r_<a>_<b> lines):")
    _table(("pair", "R_eq_ohm"), [(p.label, repr(p.r_eq_ohm)) for p in netlist.probes])
    return 0


def maps_handler(args: argparse.Namespace) -> int:
    from neatskin.errors import ConfigError
    from neatskin.layout import load_layout

    for name in ("grid_step_mm", "depth_mm", "probe_radius_mm"):
        value = getattr(args, name)
        if not value > 0:
            flag = "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} must be > 0, got {value}", field=flag, fix=f"pass a positive {flag}")
    layout = load_layout(args.layout)
    written = write_maps(
        layout,
        Path(args.out),
        grid_step_mm=args.grid_step_mm,
        depth_mm=args.depth_mm,
        probe_radius_mm=args.probe_radius_mm,
        fidelity=args.fidelity,
        show_progress=not args.quiet,
    )
    for path in written:
        print(path)
    return 0


def write_maps(
    layout,
    out_dir: Path,
    grid_step_mm: float = 0.25,
    depth_mm: float = 3.5,
    probe_radius_mm: float = 2.75,
    fidelity: str = "deformation",
    show_progress: bool = True,
) -> list[Path]:
    """Compute both kinds of map and write the PNGs and one parquet file; returns the paths written."""
    import json

    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    from neatskin import __version__
    from neatskin.skin.maps import deformation_sensitivity, grid_positions_mm, paper_sensitivity
    from neatskin.skin.model import SkinModel
    from neatskin.skin.plots import plot_pairs, plot_z

    out_dir.mkdir(parents=True, exist_ok=True)
    reps = layout.pair_class_representatives()
    paper = paper_sensitivity(layout)
    model = SkinModel(layout, fidelity=fidelity, probe_radius_mm=probe_radius_mm)
    x, y = grid_positions_mm(layout, grid_step_mm)
    with tqdm(total=x.size, desc="dense map", unit="press", disable=not show_progress) as bar:
        dense = deformation_sensitivity(model, x, y, depth_mm, progress=bar.update)
    label = f"{fidelity} model, {depth_mm:g} mm press, {2 * probe_radius_mm:g} mm probe"
    written = [
        plot_z(layout, paper, out_dir / "paper_z.png", "paper simulation: each channel +50 % (Fig. 3)"),
        plot_pairs(layout, paper, reps, out_dir / "paper_pairs.png", "paper simulation, per pair (Fig. 5)"),
        plot_z(layout, dense, out_dir / f"{fidelity}_z.png", f"max dR_eq over S\n{label}"),
        plot_pairs(layout, dense, reps, out_dir / f"{fidelity}_pairs.png", f"per pair: {label}"),
    ]
    frame = pd.concat([paper.to_frame(), dense.to_frame()], ignore_index=True)
    table = pa.Table.from_pandas(frame, preserve_index=False)
    meta = {
        "neatskin.layout": layout.source,
        "neatskin.layout_name": layout.name,
        "neatskin.software_version": __version__,
        "neatskin.depth_mm": str(depth_mm),
        "neatskin.probe_radius_mm": str(probe_radius_mm),
        "neatskin.grid_step_mm": str(grid_step_mm),
        "neatskin.fidelity": fidelity,
        "neatskin.pairs": json.dumps([p.label for p in layout.pairs]),
    }
    table = table.replace_schema_metadata(
        {**(table.schema.metadata or {}), **{k.encode(): v.encode() for k, v in meta.items()}}
    )
    data_path = out_dir / "sensitivity_maps.parquet"
    pq.write_table(table, data_path)
    written.append(data_path)
    return written

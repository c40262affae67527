"""`neatskin campaign run|resume|finish|check`: a protocol in, a campaign dataset (and its baseline report) out."""

from __future__ import annotations

import argparse
import re
import sys
from datetime import datetime
from pathlib import Path

from neatskin.cligroups import add_connect_timeout, add_out, add_quiet, command_group, positive_count, tcp_port
from neatskin.errors import CheckFailed, ConfigError, ExitCode
from neatskin.rig.summarytext import printer_time_text, run_summary
from neatskin.stopsignals import as_ctrl_c


def register(subparsers) -> None:
    sub = command_group(subparsers, "campaign", "run, resume, finish or check a press campaign")

    run = sub.add_parser("run", help="run a campaign from a protocol file")
    run.add_argument("protocol", type=Path, help="protocol TOML, e.g. protocols/paper.toml")
    rig = run.add_mutually_exclusive_group()
    rig.add_argument(
        "--dry-run",
        action="store_true",
        help="simulated printer (on a pseudo-terminal) and simulated skin and DAQ; no hardware",
    )
    rig.add_argument("--port", help="the printer's serial port, e.g. /dev/ttyUSB0 (real rig)")
    run.add_argument(
        "--daq",
        default="ni",
        choices=("ni", "simulated"),
        help="DAQ of a real run: ni, or simulated (the simulated skin follows the printer's motion; no DAQ wired)",
    )
    add_out(run, "campaign folder (default: runs/<name>-<date>-<time>)")
    add_connect_timeout(run, None, "seconds to wait for the printer's boot banner (real rig default 5)")
    run.add_argument(
        "--limit", type=positive_count, help="stop after this many presses, 1 or more (the campaign stays resumable)"
    )
    run.add_argument("--no-report", action="store_true", help="skip the baseline report at the end")
    add_quiet(run)
    run.add_argument(
        "--monitor",
        action="store_true",
        help="also serve the live page (neatskin monitor, in its own process) on 127.0.0.1 while it runs",
    )
    run.add_argument(
        "--monitor-port",
        type=tcp_port,
        default=8765,
        metavar="N",
        help="the live page's port (default 8765; 0 picks a free one)",
    )
    run.set_defaults(handler=_run)

    resume = sub.add_parser("resume", help="finish an interrupted campaign, no press lost or duplicated")
    resume.add_argument("folder", type=Path, help="the campaign folder")
    resume.add_argument("--port", help="serial port of a real run (default: as recorded)")
    resume.add_argument("--no-report", action="store_true", help="skip the baseline report at the end")
    add_quiet(resume)
    resume.set_defaults(handler=_resume)

    finish = sub.add_parser(
        "finish",
        help="complete a campaign whose presses are all on disk: consolidate, restore a damaged presses.parquet "
        "from its copy, write the missing physical limit and report",
    )
    finish.add_argument("folder", type=Path, help="the campaign folder")
    finish.add_argument("--no-report", action="store_true", help="do not write a missing baseline report")
    add_quiet(finish)
    finish.set_defaults(handler=_finish)

    check = sub.add_parser("check", help="validate a protocol and print its plan and time estimate, moving nothing")
    check.add_argument(
        "protocol",
        type=Path,
        help="protocol TOML, e.g. protocols/paper.toml, or a campaign folder (the protocol and files it ran with)",
    )
    check.set_defaults(handler=_check)

    plan = sub.add_parser(
        "plan", help="predicted error for new positions against rig hours, from simulated campaigns, before pressing"
    )
    plan.add_argument("protocol", type=Path, help="protocol TOML, e.g. protocols/paper.toml")
    plan.add_argument("--seeds", type=int, default=5, help="campaign seeds per size (default 5)")
    plan.add_argument(
        "--model",
        default="extra_trees",
        help="the baseline fitted (default extra_trees, the best for new positions on the FE skin; one LM network a "
        "seed fails now and then on its saturated cut pairs, which swamps a mean over 5 seeds)",
    )
    plan.add_argument("--jobs", type=int, default=2, help="joblib processes (default 2)")
    plan.add_argument("--no-adaptive", action="store_true", help="skip the adaptive design")
    add_out(plan, "folder for the CSV and PNG (default campaign-plan)", default=Path("campaign-plan"))
    add_quiet(plan)
    plan.set_defaults(handler=_plan)


@as_ctrl_c()  # SIGTERM, SIGHUP: as Ctrl-C (the press in flight finishes, the probe parks)
def _run(args: argparse.Namespace) -> int:
    from neatskin.errors import ConfigError
    from neatskin.rig.protocol import load_protocol

    try:
        protocol = load_protocol(args.protocol)
    except ConfigError as exc:  # a refused current: the fix `campaign check` gives, with its pressed figures
        from neatskin.rig.railcheck import with_pressed_figures

        problems = with_pressed_figures(args.protocol, exc.problems, solve_kernel=False)
        if problems == list(exc.problems):
            raise
        raise ConfigError(problems=problems) from exc
    if not args.dry_run and not args.port:
        raise ConfigError(
            "choose the rig: --dry-run (simulated, no hardware) or --port PORT (the real printer)",
            field="--dry-run/--port",
            fix=f"e.g. neatskin campaign run {args.protocol} --dry-run",
        )
    forecast = None
    if args.dry_run:
        _prestart_skin_worker(protocol)
        _preimport("scipy.ndimage")  # the FSR labelling's (0.3 s): at the first press it would be on the critical path
    else:  # a real run builds no simulator (the skin model): its rails forecast runs in a child, from now on
        forecast = _start_rails_forecast(protocol.path)
    from neatskin.rig.runner import run_campaign  # after the prestart: its imports overlap the worker's start

    plan = None
    if args.dry_run:  # built once: the rails warning draws its presses, the runner presses it
        from neatskin.rig.plan import build_plan

        plan = build_plan(protocol)
    _warn_pressed_rails(protocol, forecast, plan)  # before any motion
    out = args.out or default_campaign_folder(protocol.name)
    monitor = _start_monitor(out, args.monitor_port) if args.monitor else None
    try:
        result = run_campaign(
            protocol,
            out,
            dry_run=args.dry_run,
            port=args.port,
            daq_kind=args.daq,
            progress=not args.quiet,
            limit=args.limit,
            report=not args.no_report,
            connect_timeout_s=args.connect_timeout_s,
            plan=plan,
        )
    finally:
        if monitor is not None:
            monitor.terminate()
            monitor.wait(10)
    if result.report_summary:
        print(result.report_summary)
    print(run_summary(result))
    if monitor is not None:
        print(f"the live page stopped with the campaign; to look again: neatskin monitor {out}")
    return ExitCode.INTERRUPTED if result.interrupted else ExitCode.OK


RAILS_FORECAST_TIMEOUT_S = 60.0  # the child's cap: the paper protocol's takes ~2 s on a loaded machine


def _start_rails_forecast(path: Path):
    """`python -m neatskin.rig.railcheck PROTOCOL` in a child (a real run's process builds no simulator)."""
    import subprocess

    return subprocess.Popen(
        [sys.executable, "-m", "neatskin.rig.railcheck", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: the cap ends it with every process it started
    )


def _end_forecast(forecast) -> None:
    """End the forecast child and whatever it started (a kernel solve's workers hold its pipes open)."""
    import os
    import signal

    try:
        os.killpg(forecast.pid, signal.SIGKILL)  # the group outlives its leader while a worker of it lives
    except ProcessLookupError:
        pass
    forecast.communicate()


def _warn_pressed_rails(protocol, forecast=None, plan=None, resumed: Path | None = None) -> None:
    """`campaign check`'s pressed-rails warning, in its words, before any motion: a technician who runs without the
    check sees it too (on stderr, before the progress bar); nothing when every press stays inside the rails. A dry
    run draws the protocol's presses through its skin model here (about 0.2 s of CPU for the paper protocol's 2800,
    while the prestarted skin worker starts on the other core); a real run reads the line from its `forecast` child,
    started before the runner's imports, and runs on with a note if the child fails or passes its cap. `plan`: the
    dry run's, which its runner then presses (built once). `resumed`: the campaign folder a resume presses on; the
    line then counts only the presses not on disk yet ("of the N left"; the forecast child reads the folder itself)."""
    if forecast is None:
        from neatskin.rig.railcheck import pressed_rails_warning, recorded_press_ids

        done = recorded_press_ids(resumed) if resumed is not None else None
        warning = pressed_rails_warning(protocol, plan, done)
    else:
        import subprocess

        answered = False
        try:
            stdout, stderr = forecast.communicate(timeout=RAILS_FORECAST_TIMEOUT_S)
            answered = True
        except subprocess.TimeoutExpired:
            stdout, stderr = "", f"no answer within {RAILS_FORECAST_TIMEOUT_S:g} s"
        finally:  # the cap passed, or Ctrl-C (its own session does not get the terminal's): end it with its group
            if not answered:
                _end_forecast(forecast)
        if forecast.returncode == 0:
            warning = stdout.strip() or None
        else:
            why = (stderr.strip().splitlines() or [f"exit {forecast.returncode}"])[-1]
            warning = (
                f"electrical, pressed: not forecast ({why}); `neatskin campaign check {protocol.path}` prints "
                "how many presses would pass the mux rails"
            )
    if warning:
        print(f"{protocol.path}: {warning}", file=sys.stderr, flush=True)


def _prestart_skin_worker(protocol) -> None:
    """A dry run of a features scene computes its estimates in a skin worker (neatskin.rig.dryrig.use_skin_worker
    has the rule): launch its process now, so its interpreter start and imports overlap this process's imports,
    plan and folder instead of the first presses; the dry rig adopts it, or ends it when the campaign turns out
    to compute inline (under the batching writer's size). Only a hint: without it the rig starts its own."""
    if getattr(protocol.scene, "signal", None) != "features":
        return
    from neatskin.errors import ConfigError
    from neatskin.sim.skinworker import forced_by_env, prestart, usable_cores

    try:
        forced = forced_by_env()
    except ConfigError:
        return  # the dry rig reports it, with the campaign's other errors
    if forced is False or (forced is None and usable_cores() < 2):
        return
    prestart(preload=("neatskin.sim.dryscene", "pyarrow.parquet"))


def _preimport(module: str) -> None:
    """Import `module` in a thread now, while this process's own imports and the campaign's start (the printer's
    boot, the skin worker's start) leave the CPU idle in waits, instead of where its first use is."""
    import importlib
    import threading

    threading.Thread(target=importlib.import_module, args=(module,), name=f"import {module}", daemon=True).start()


def _start_monitor(out: Path, port: int):
    """`neatskin monitor OUT` in its own process (it reads only the folder; it prints its URL and token),
    waited for (up to 15 s) so its URL is on screen before the first press."""
    import socket
    import subprocess
    import sys
    import time

    port = _monitor_port_free(port)
    proc = subprocess.Popen([sys.executable, "-m", "neatskin", "monitor", str(out), "--port", str(port)])
    deadline = time.monotonic() + 15.0
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            break
        except OSError:
            time.sleep(0.1)
    return proc


def _monitor_port_free(port: int) -> int:
    """The live page's port, checked here before anything starts (0: a free one, chosen here so the run knows
    it): a port in use is one ConfigError naming --monitor-port (--port is the printer's here)."""
    import errno
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError as exc:
            in_use = exc.errno == errno.EADDRINUSE
            raise ConfigError(
                f"the live page cannot listen on 127.0.0.1:{port}: {exc.strerror or exc}",
                field="--monitor-port",
                fix="choose another port (--monitor-port 0 picks a free one), or stop the other monitor"
                if in_use
                else "use a port above 1023 (default 8765)",
            ) from exc
        return int(probe.getsockname()[1])


def default_campaign_folder(name: str, now: datetime | None = None) -> Path:
    """runs/<name>-<date>-<time>, with the name reduced to letters, digits, '.', '_' and '-' (no leading dot),
    so no protocol name (`../../x`, `/etc/x`) can place the campaign outside runs/."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name)
    safe = re.sub(r"_+", "_", re.sub(r"\.{2,}", "_", safe)).strip("._-") or "campaign"
    folder = Path("runs") / f"{safe[:100]}-{(now or datetime.now()).strftime('%Y%m%d-%H%M%S')}"
    return folder


@as_ctrl_c()  # SIGTERM, SIGHUP: as Ctrl-C (the press in flight finishes, the probe parks)
def _finish(args: argparse.Namespace) -> int:
    from neatskin.rig.runner import finish_campaign

    result = finish_campaign(args.folder, report=not args.no_report, progress=not args.quiet)
    if result.report_summary:
        print(result.report_summary)
    print(f"campaign complete: {result.completed}/{result.planned} presses in {result.folder}")
    return 0


@as_ctrl_c()  # SIGTERM, SIGHUP: as Ctrl-C (the press in flight finishes, the probe parks)
def _resume(args: argparse.Namespace) -> int:
    kwargs = {"progress": not args.quiet, "report": not args.no_report}
    if args.port:
        kwargs.update(dry_run=False, port=args.port)
    # the pressed-rails warning, as `campaign run` prints it, from the campaign's recorded protocol, counting the
    # presses left (those not on disk): a real resume's in a child started now (its process builds no simulator), a
    # dry one's in this process, once the folder's checks passed and presses are left (a complete campaign only
    # finishes: no motion, no line)
    forecast = _start_rails_forecast(args.folder) if _resumes_real(args) else None
    folder = Path(args.folder)
    try:
        from neatskin.rig.runner import resume_campaign

        result = resume_campaign(
            args.folder,
            before_motion=lambda protocol, plan: _warn_pressed_rails(protocol, forecast, plan, resumed=folder),
            **kwargs,
        )
    finally:
        if forecast is not None and forecast.returncode is None:  # the warning was not reached (an error, Ctrl-C)
            _end_forecast(forecast)
    if result.report_summary:
        print(result.report_summary)
    print(run_summary(result))
    return ExitCode.INTERRUPTED if result.interrupted else ExitCode.OK


def _resumes_real(args: argparse.Namespace) -> bool:
    """Whether `campaign resume` presses on the real rig: --port, or a real campaign's manifest, and the campaign is
    not complete (then it only finishes: no forecast child). A folder whose manifest cannot be read says False here:
    the resume itself reports it."""
    from neatskin.datasets.manifest import read_manifest
    from neatskin.errors import NeatskinError
    from neatskin.rig.folder import rig_kind

    try:
        manifest = read_manifest(args.folder)
        return manifest.get("status") != "complete" and (bool(args.port) or rig_kind(args.folder, manifest) == "real")
    except (NeatskinError, OSError, ValueError):
        return False


@as_ctrl_c()  # SIGTERM, SIGHUP: as Ctrl-C (a kernel solve's workers end with it)
def _check(args: argparse.Namespace) -> int:
    from neatskin.gcode.program import low_park_warning
    from neatskin.rig.folder import INPUTS_DIR, load_inputs
    from neatskin.rig.plan import build_plan
    from neatskin.rig.protocol import load_protocol

    path = Path(args.protocol)
    recorded = path / INPUTS_DIR / "protocol.toml"
    try:  # a campaign folder: the protocol and files it ran with, its inputs/ copies (as resume uses them)
        if path.is_dir() and not recorded.is_file():
            raise ConfigError(
                f"{path} is a folder, and no campaign folder (no {INPUTS_DIR}/protocol.toml in it)",
                file=str(path),
                fix="give a protocol file (e.g. protocols/paper.toml) or a campaign folder",
            )
        protocol = load_inputs(path) if path.is_dir() else load_protocol(path)
        plan = build_plan(protocol)
    except ConfigError as exc:  # the check's verdict: the protocol fails it
        from neatskin.rig.railcheck import with_pressed_figures

        checked = recorded if path.is_dir() else path
        raise CheckFailed(problems=with_pressed_figures(checked, exc.problems)) from exc
    positions = len(set(plan.program.presses.position_ids.tolist()))  # no block needs formatting to count
    print(f"{protocol.path}: ok")
    print(
        f"  {plan.n_presses} presses ({positions} positions), layout {protocol.layout.name} "
        f"({protocol.layout.n_channels} channels, {len(protocol.layout.pairs)} pairs)"
    )
    print(
        f"  sweep {plan.sweep.n_samples} samples = {plan.sweep.duration_s * 1000:.1f} ms, "
        f"{plan.n_sweeps} sweeps recorded per press, hold {plan.hold_s} s"
    )
    print(f"  {printer_time_text(plan.printer_time_s, plan.n_presses)}")
    if long_hold := plan.long_hold_warning():  # a warning, not a refusal: the config allows up to 3600 s
        print(f"  warning: {long_hold}")
    if low_park := low_park_warning(protocol.printer):
        print(f"  warning: {low_park}")
    print(f"  resources (upper bounds): {protocol.resources.summary()}")
    print(f"  electrical: {protocol.electrical.summary()}")
    from neatskin.rig.railcheck import missing_kernel, pressed_rails_text

    solving = missing_kernel(protocol)
    if solving:  # the pressed line needs it: say why nothing is printed for minutes
        from neatskin.skin.kernel import solve_notice

        print(f"  electrical, pressed: {solve_notice()}", flush=True)
    try:
        line = pressed_rails_text(protocol)
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM, SIGHUP: joblib has ended the solve's workers; say what is left
        if not solving:
            raise
        raise KeyboardInterrupt(
            "the pinch kernel's solve was stopped, nothing cached: `neatskin campaign check` starts it again"
        ) from None
    print(f"  {line}")
    return 0


def _plan(args: argparse.Namespace) -> int:
    from neatskin.rig.forecastcli import run_plan

    return run_plan(
        args.protocol,
        args.out,
        seeds=args.seeds,
        model=args.model,
        jobs=args.jobs,
        adaptive=not args.no_adaptive,
        progress=not args.quiet,
    )

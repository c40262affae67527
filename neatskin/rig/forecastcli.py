"""The shell of `neatskin campaign plan`: load the protocol, run the plan, print the table, write CSV and PNG."""

from __future__ import annotations

from pathlib import Path

from neatskin.errors import ConfigError


def run_plan(
    protocol_path: Path, out: Path, *, seeds: int, model: str, jobs: int, adaptive: bool, progress: bool = True
) -> int:
    from neatskin.baselines.models import MODEL_NAMES
    from neatskin.rig.forecast import adaptive_verdict, format_plan, hours_for_error, plan_campaign, plot_plan
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.simcampaign import CampaignSize, rig_hours

    if seeds < 2:
        raise ConfigError(
            f"--seeds {seeds} gives no spread",
            file="<command line>",
            field="--seeds",
            fix="use at least 2 seeds (5 by default)",
        )
    if model not in MODEL_NAMES:
        raise ConfigError(
            f"unknown model {model!r}",
            file="<command line>",
            field="--model",
            fix=f"choose from {', '.join(MODEL_NAMES)}",
        )
    protocol = load_protocol(protocol_path)
    press = protocol.press
    own = rig_hours(protocol, CampaignSize(press.positions.count, press.press.repeats, press.press.depth_mm))
    frame = plan_campaign(protocol, seeds=seeds, model=model, adaptive=adaptive, n_jobs=jobs, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    frame.to_csv(out / "campaign_plan.csv", index=False)
    png = plot_plan(frame, out / "campaign_plan.png", own)
    print(format_plan(frame, str(protocol_path), own))
    for target in (4.0, 3.0, 2.5, 2.0):
        hours = hours_for_error(frame, target)
        print(f"  {target:g} mm for new positions: " + (f"about {hours:.2f} rig hours" if hours else "not reached"))
    if adaptive:
        print("adaptive design (half the positions at random, the rest where the first fit is worst):")
        for line in adaptive_verdict(frame):
            print("  " + line)
    print(f"wrote {out / 'campaign_plan.csv'} and {png}")
    return 0

"""The words of `neatskin design validate`: the terminal table and report.md's section, from a Validation."""

from __future__ import annotations

from neatskin.design.validate import (
    CAMPAIGN_SEEDS,
    FOLDS,
    LEVEL_TOLERANCE,
    NEGATIVE_PINCH,
    SECTION,
    TRANSFER_TOLERANCE,
    Validation,
)


def _cell(values) -> str:
    return f"{values.mean():.2f} ± {values.std(ddof=1):.2f}" if len(values) > 1 else f"{values.mean():.2f}"


def table_lines(v: Validation) -> list[str]:
    lines = [
        "| candidate | study mm | campaigns as the study assumes mm | study-trained model on them mm (gap) "
        "| campaigns in the protocol's scene mm | level | transfer |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in v.checks:
        lines.append(
            f"| {c.label} | {_cell(c.study_mm)} | {_cell(c.campaign_mm)} | {_cell(c.transfer_mm)} "
            f"({c.transfer_gap_mm:+.2f}) | {_cell(c.scene_mm)} | {'agree' if c.level_agrees else 'disagree'} "
            f"| {'agree' if c.transfer_agrees else 'disagree'} |"
        )
    return lines


def head_to_head_lines(v: Validation) -> list[str]:
    """Optimised against boundary at each electrode count: both sides' errors and the paired differences."""
    lines = []
    for h in v.head_to_head:
        (ds, ss), (dc, sc) = h.study_diff_mm, h.scene_diff_mm
        lines.append(
            f"{h.optimised.label} against {h.boundary.label}: study {_cell(h.optimised.study_mm)} against "
            f"{_cell(h.boundary.study_mm)} mm (difference {ds:+.2f} ± {ss:.2f} SE over {len(h.optimised.study_mm)} "
            f"paired seeds); campaigns in the protocol's scene {_cell(h.optimised.scene_mm)} against "
            f"{_cell(h.boundary.scene_mm)} mm (difference {dc:+.2f} ± {sc:.2f} SE over {len(h.optimised.scene_mm)} "
            f"paired seeds): {h.order}"
        )
    return lines


def verdict_lines(v: Validation) -> list[str]:
    order_study = " < ".join(c.label for c in sorted(v.checks, key=lambda c: c.study_mm.mean()))
    order_scene = " < ".join(c.label for c in sorted(v.checks, key=lambda c: c.scene_mm.mean()))
    lines = [f"note: {v.note}"] if v.note else []
    lines += [
        f"ranking: study {order_study}; campaigns {order_scene}; Kendall tau {v.kendall_tau:.2f}: "
        + ("agree (no pair the study separates is reversed)" if v.ranking_agrees else "disagree"),
        *head_to_head_lines(v),
    ]
    if v.power:
        detected = ", ".join(f"{s:g}" for s, d in v.power if d) or "none"
        missed = ", ".join(f"{s:g}" for s, d in v.power if not d) or "none"
        smallest = v.smallest_detected
        lines.append(
            f"power (first candidate, 3 seeds): pinch scaled by {detected} detected; by {missed} not; smallest "
            f"change detected {'none' if smallest is None else f'{100 * smallest:.0f} %'}"
        )
    scale = "" if v.pinch_scale == 1.0 else f" (campaigns' pinch x {v.pinch_scale:g})"
    lines.append(f"verdict{scale}: " + ("agree" if v.agree else "disagree"))
    return lines


def markdown(v: Validation, study_name: str, protocol: str) -> str:
    negative = v.pinch_scale != 1.0
    return "\n".join(
        [
            SECTION,
            "",
            f"Study `{study_name}` against simulated campaigns (`neatskin.rig.simcampaign`) built from `{protocol}`: "
            f"the protocol's position strategy, {CAMPAIGN_SEEDS} campaign seeds not the study's, {FOLDS}-fold grouped "
            "splits, the baselines' distance-weighted kNN; the study's own candidates with fixed placements"
            + (", and its optimised placements from its run" if v.head_to_head else "")
            + (f"; **negative control: the campaigns' skin has its pinch x {v.pinch_scale:g}**" if negative else "")
            + ". Mean Euclidean error, mean ± std over seeds.",
            "",
            *table_lines(v),
            "",
            f"Level: study against campaigns in the scene the study assumes, within 2 combined standard errors + "
            f"{100 * LEVEL_TOLERANCE:.0f} % (assumed: the positions' strategy differs). Transfer: a kNN trained on the "
            f"study's simulated dataset scored on those campaigns, against the campaigns' own kNN, within 2 standard "
            f"errors + {100 * TRANSFER_TOLERANCE:.0f} % (assumed). The learned error alone barely moves with the "
            "physics; the transfer check is the one with power. Ranking: the protocol's own scene.",
            "",
            *[f"- {line}" for line in verdict_lines(v)],
            "",
            f"The negative control (`--negative-control`, pinch x {NEGATIVE_PINCH:g}) must disagree.",
            "",
        ]
    )

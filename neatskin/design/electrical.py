"""The design study's electrical check: the campaign protocol's own (`neatskin.rig.protocol.electrical_check`), run
on each candidate skin with the mux board and excitation the study assumes, so a study cannot call compliant a skin
whose protocol would be refused, nor the other way round.

What is assumed (the study's `[excitation]` and `[acquisition]` keys, defaults as a protocol's and its wiring's):
symmetric mux rails +-`rails_v` (MAX4052 class at +-8 V), `r_on_ohm` per switch and `r_on_mismatch_ohm`, the
galvanostat's `compliance_v`, the ADC's `adc_range_v` over the monitor's `voltage_gain`, and a press raising the
largest pair R_eq to at most `press_margin` x the undeformed skin's. The check is that of the undeformed skin with
the margin; the study also reports the largest pair R_eq over its simulated presses, and whether the margin covers it.
"""

from __future__ import annotations

from typing import Any

from neatskin.config.files import ElectricalTable
from neatskin.design.study import Study
from neatskin.layout import Layout
from neatskin.rig.protocol import ElectricalCheck, electrical_check


def assumed_mux(study: Study) -> ElectricalTable:
    """The mux chips' limits the study assumes: a wiring file's [electrical] with rails +-rails_v."""
    return ElectricalTable(
        supply_positive_v=study.rails_v,
        supply_negative_v=-study.rails_v,
        r_on_ohm=study.r_on_ohm,
        r_on_mismatch_ohm=study.r_on_mismatch_ohm,
    )


def candidate_electrical(study: Study, layout: Layout) -> ElectricalCheck:
    """The protocol's electrical check of one candidate skin (its layout with its electrodes)."""
    return electrical_check(
        layout,
        assumed_mux(study),
        amplitude_a=study.amplitude_a,
        press_margin=study.press_margin,
        compliance_v=study.compliance_v,
        adc_range_v=study.adc_range_v,
        voltage_gain=study.voltage_gain,
    )


def electrical_columns(check: ElectricalCheck, pressed_max_pair_ohm: float, press_margin: float) -> dict[str, Any]:
    """A candidate's electrical columns of candidates.parquet."""
    return {
        "max_pair_ohm": pressed_max_pair_ohm,
        "undeformed_max_pair_ohm": check.largest_r_eq_ohm,
        "electrical_pair": check.largest_pair,
        "peak_voltage_v": check.peak_v,
        "electrical_limit_v": check.limit_v,
        "electrical_limit": check.limit_name,
        "compliant": check.within_limit,
        "press_margin_covers": bool(pressed_max_pair_ohm <= press_margin * check.largest_r_eq_ohm),
    }

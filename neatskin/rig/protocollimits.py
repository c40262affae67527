"""What a campaign protocol would demand of the rig, and its limits: the run's resources and the excitation's peak.

`estimate_resources` bounds one press's samples and the campaign's bytes and rig time from the protocol alone,
`resource_cap_problems` holds them against the caps of `neatskin.config.files`; `electrical_check` puts the worst-case
peak voltage on the undeformed skin against the mux rails, the galvanostat's compliance and the ADC's reach, and
`electrical_problems` words the refusal. `rig.protocol` runs them while loading a protocol (and re-exports the
names callers import from there); the design study calls `electrical_check` for each candidate skin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neatskin.config import files as schema
from neatskin.config.files import AcquisitionSettings, Excitation
from neatskin.errors import Problem
from neatskin.skin.network import equivalent_resistance

WAVEFORM_BYTES_PER_SAMPLE = 3 * 8  # V, I, FSR as float64


@dataclass(frozen=True)
class ResourceEstimate:
    """What the run would take, estimated from the protocol alone (upper bounds, before the plan is built)."""

    presses: int
    samples_per_press: int
    bytes_per_press: int  # one press's raw samples in memory
    waveform_bytes: int  # stored raw samples of the whole campaign (0 unless record.waveforms)
    rig_time_s: float

    def summary(self) -> str:
        return (
            f"{self.presses} presses, <= {self.samples_per_press} samples ({self.bytes_per_press / 2**20:.1f} MiB) "
            f"per press, {self.waveform_bytes / 2**30:.2f} GiB of waveforms, rig time <= {self.rig_time_s / 3600:.2f} h "
            "(a bound from the protocol alone: slowest feed, a bed-diagonal travel and 0.5 s of recording per "
            "press, homing; the campaign cap checks it)"
        )


@dataclass(frozen=True)
class ElectricalCheck:
    """The excitation's worst-case peak voltage on the undeformed skin times the press margin, and its limit."""

    largest_pair: str
    largest_r_eq_ohm: float
    peak_v: float
    limit_v: float
    limit_name: str

    @property
    def headroom(self) -> float:
        return self.limit_v / self.peak_v

    @property
    def within_limit(self) -> bool:
        """The verdict: the protocol is refused (and a design candidate marked not compliant) when False."""
        return self.peak_v <= self.limit_v

    def summary(self) -> str:
        return (
            f"peak {self.peak_v:.2f} V (pair {self.largest_pair}, {self.largest_r_eq_ohm:.0f} ohm undeformed, "
            f"with the press margin and R_on), limit {self.limit_v:.2f} V ({self.limit_name}), "
            f"{self.headroom:.2f}x headroom"
        )


def estimate_resources(press: Any, printer: Any, acq: AcquisitionSettings, waveforms: bool) -> ResourceEstimate:
    """Upper bounds of one press's samples and the campaign's bytes and rig time, from the protocol alone."""
    spec = press.press
    presses = press.positions.count * spec.repeats
    z_travel_mm = printer.safe_height_mm + spec.depth_mm
    motion_s = 2 * z_travel_mm / min(printer.z_feed_mm_s, printer.press_feed_mm_s)
    per_press_s = spec.hold_s + motion_s + 0.5  # the runner records 0.5 s beyond the press
    travel_s = math.hypot(printer.bed_x_mm, printer.bed_y_mm) / printer.travel_feed_mm_s
    samples = math.ceil(per_press_s * acq.rate_hz)
    per_press_bytes = samples * WAVEFORM_BYTES_PER_SAMPLE
    return ResourceEstimate(
        presses=presses,
        samples_per_press=samples,
        bytes_per_press=per_press_bytes,
        waveform_bytes=per_press_bytes * presses if waveforms else 0,
        rig_time_s=presses * (per_press_s + travel_s) + printer.homing_time_s,
    )


def resource_cap_problems(r: ResourceEstimate, press: Any, acq: AcquisitionSettings, source: str) -> list[Problem]:
    problems = []
    if r.samples_per_press > schema.MAX_SAMPLES_PER_PRESS:
        problems.append(
            Problem(
                f"one press would record {r.samples_per_press:.3g} samples ({r.bytes_per_press / 2**30:.3g} GiB), "
                f"beyond the cap of {schema.MAX_SAMPLES_PER_PRESS:.3g}",
                source,
                "press.hold_s",
                f"shorten press.hold_s ({press.press.hold_s:g} s) or lower acquisition.rate_hz ({acq.rate_hz:g} Hz)",
            )
        )
    if r.waveform_bytes > schema.MAX_WAVEFORM_BYTES:
        problems.append(
            Problem(
                f"the campaign would store {r.waveform_bytes / 2**30:.3g} GiB of waveforms, beyond the cap of "
                f"{schema.MAX_WAVEFORM_BYTES / 2**30:.0f} GiB",
                source,
                "record.waveforms",
                "set record.waveforms = false (features only), or fewer presses, a shorter hold or a lower rate",
            )
        )
    if r.rig_time_s > schema.MAX_RIG_TIME_S:
        problems.append(
            Problem(
                f"the campaign would take about {r.rig_time_s / 86400:.3g} days of rig time, beyond the cap of "
                f"{schema.MAX_RIG_TIME_S / 86400:.0f} days",
                source,
                "positions.count",
                "split it into several campaigns (fewer positions or repeats each), or shorten press.hold_s",
            )
        )
    return problems


def check_electrical(layout: Any, wiring: Any, excitation: Excitation, acq: AcquisitionSettings) -> ElectricalCheck:
    """Worst-case peak voltage: amplitude x (largest pair R_eq of the undeformed skin x press margin
    + 2 R_on + R_on mismatch), against the lowest of the mux rails, the compliance and the ADC's reach."""
    return electrical_check(
        layout,
        wiring.electrical,
        amplitude_a=excitation.amplitude_a,
        press_margin=excitation.press_margin,
        compliance_v=excitation.compliance_v,
        adc_range_v=acq.adc_range_v,
        voltage_gain=acq.voltage_gain,
    )


def electrical_check(
    layout: Any,
    electrical: schema.ElectricalTable,
    *,
    amplitude_a: float,
    press_margin: float,
    compliance_v: float,
    adc_range_v: float,
    voltage_gain: float,
) -> ElectricalCheck:
    """`check_electrical` on plain values: a layout, the mux chips' [electrical] limits and the excitation and ADC
    numbers (the design study calls it for each candidate skin, with the wiring it assumes)."""
    import numpy as np

    r_eq = np.asarray(equivalent_resistance(layout, 1.0 / layout.channel_resistance_ohm))
    # symmetric pairs tie up to rounding: name the first of them in pair order, whatever the solver's last bit
    k = int(np.argmax(np.round(r_eq / r_eq.max(), 9)))
    e = electrical
    path_ohm = float(r_eq[k]) * press_margin + 2 * e.r_on_ohm + e.r_on_mismatch_ohm
    limits = {
        f"mux supply rails ({e.supply_negative_v:g} V .. +{e.supply_positive_v:g} V)": min(
            e.supply_positive_v, -e.supply_negative_v
        ),
        "galvanostat compliance (excitation.compliance_v)": compliance_v,
        "ADC range over the voltage gain (acquisition.adc_range_v / voltage_gain)": adc_range_v / voltage_gain,
    }
    name = min(limits, key=lambda n: limits[n])
    return ElectricalCheck(layout.pairs[k].label, float(r_eq[k]), amplitude_a * path_ohm, limits[name], name)


CLIP_MESSAGE = "the excitation would clip"  # the refusal's opening (rig.railcheck adds its pressed figures)


def electrical_problems(
    check: ElectricalCheck, layout: Any, wiring: Any, excitation: Excitation, source: str
) -> list[Problem]:
    if check.within_limit:
        return []
    e = wiring.electrical
    amp_max = excitation.amplitude_a * check.limit_v / check.peak_v
    return [
        Problem(
            f"{CLIP_MESSAGE}: {excitation.amplitude_a * 1e3:g} mA x ({check.largest_r_eq_ohm:.0f} ohm "
            f"(pair {check.largest_pair}, undeformed) x {excitation.press_margin:g} press margin + 2 x "
            f"{e.r_on_ohm:g} ohm R_on + {e.r_on_mismatch_ohm:g} ohm mismatch) = {check.peak_v:.3g} V peak, beyond "
            f"the {check.limit_name}: {check.limit_v:.3g} V",
            source,
            "excitation.amplitude_a",
            f"lower amplitude_a to <= {amp_max * 1e3:.3g} mA, or use a more conductive fluid (skin "
            f"resistivity_ohm_m = {layout.resistivity_ohm_m:g} ohm m in {_beside(layout.source, source)}), or other "
            "rails (wiring [electrical])",
        )
    ]


def _beside(path: str, protocol: str) -> str:
    """`path` as seen from the protocol's folder (`skins/paper.toml` for paper.toml's skin), else whole: a bare
    file name can be the protocol's own (paper.toml and skins/paper.toml)."""
    try:
        return Path(path).resolve().relative_to(Path(protocol).resolve().parent).as_posix()
    except ValueError:
        return str(path)

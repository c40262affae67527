"""The NI USB-6229 backend through the `nidaqmx` package (optional extra `ni`), imported only when this backend is opened.

Three tasks share the AI sample clock: AI (voltage, current, FSR; finite, N samples) is the
master; AO (the excitation command to the galvanostat) and DO (the mux lines, port0 only:
the USB-6229's only hardware-timed digital port) are slaved to "/Dev1/ai/SampleClock", written
before they start, and started before the AI so they wait for its first clock edge. Sample n
of all three is therefore the same clock tick.

`plan_acquisition` builds everything the tasks need as plain data (channels, ranges, the AO
waveform, the DO port words, the clock route); `NiDAQ.acquire` only applies it. The plan is
tested without hardware; the apply step is not verified on a device (see docs/acquisition.md).
"""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass, field

import numpy as np

from neatskin.acquisition.daq.base import Acquisition, Daq, DaqConfig
from neatskin.acquisition.sequence import Sweep
from neatskin.errors import ConfigError, HardwareError

USB6229_AI_AGGREGATE_HZ = 250_000.0
IDLE_TAIL_SAMPLES = 2
_LINE_RE = re.compile(r"^port([0-9]+)/line([0-9]+)$")


@dataclass(frozen=True)
class AiChannelPlan:
    physical: str  # "Dev1/ai0"
    name: str  # "voltage_v"
    min_v: float
    max_v: float
    terminal: str = "DIFF"


@dataclass(frozen=True, eq=False)
class NiTaskPlan:
    device: str
    rate_hz: float
    n_samples: int  # clocked samples, the idle tail included
    n_data: int  # samples returned (whole sweeps)
    clock_source: str  # "/Dev1/ai/SampleClock"
    ai: tuple[AiChannelPlan, ...]
    ao_channel: str
    ao_range_v: float
    ao_data_v: np.ndarray = field(repr=False)  # (samples,)
    do_channel: str = ""  # "Dev1/port0/line0,Dev1/port0/line1,..."
    do_data: np.ndarray | None = field(default=None, repr=False)  # (samples,) uint32 port0 words
    to_physical: np.ndarray | None = field(default=None, repr=False)  # (3,)
    timeout_s: float = 10.0


def line_bits(line_names: tuple[str, ...]) -> np.ndarray:
    """Port0 bit of every digital line; refuses lines the USB-6229 cannot clock."""
    bits = []
    for name in line_names:
        m = _LINE_RE.match(name)
        if not m or m.group(1) != "0" or int(m.group(2)) > 31:
            raise ConfigError(
                f"digital line '{name}' cannot be hardware-timed on the USB-6229",
                field="lines",
                fix="wire A, B and the inhibits to port0/line0..31 and say so in the wiring file",
            )
        bits.append(int(m.group(2)))
    return np.array(bits, dtype=np.uint32)


def pack_lines(lines: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """(samples, lines) bool -> (samples,) uint32 port words, line k on bit bits[k]."""
    weights = (np.uint32(1) << bits.astype(np.uint32)).astype(np.uint32)
    return (lines.astype(np.uint32) * weights).sum(axis=1).astype(np.uint32)


def plan_acquisition(
    config: DaqConfig, sweep: Sweep, n_sweeps: int = 1, start_time_s: float = 0.0, timeout_margin_s: float = 5.0
) -> NiTaskPlan:
    """Everything the three tasks need, as data (pure)."""
    if abs(sweep.rate_hz - config.rate_hz) > 1e-9:
        raise ConfigError(
            f"sweep built at {sweep.rate_hz} Hz, DAQ configured at {config.rate_hz} Hz",
            field="rate_hz",
            fix="build the sweep with the DAQ's rate",
        )
    if config.rate_hz * len(config.ai_channels) > USB6229_AI_AGGREGATE_HZ:
        raise ConfigError(
            f"{len(config.ai_channels)} AI channels at {config.rate_hz} Hz exceed the USB-6229's "
            f"{USB6229_AI_AGGREGATE_HZ:.0f} S/s aggregate",
            field="rate_hz",
            fix="lower rate_hz",
        )
    if not isinstance(n_sweeps, int) or n_sweeps < 1:
        raise ConfigError(
            f"n_sweeps must be a positive integer, got {n_sweeps!r}", field="n_sweeps", fix="acquire >= 1 sweep"
        )
    dev = config.device
    n = n_sweeps * sweep.n_samples
    start = int(round(start_time_s * config.rate_hz))
    index = start + np.arange(n, dtype=np.int64)
    period = config.samples_per_period
    whole = round(period)
    phase = 2 * np.pi * ((index % whole) / whole if abs(period - whole) < 1e-9 else index / period)
    ao = config.ao_v_per_a * config.amplitude_a * np.sin(phase)
    ranges = (config.voltage_range_v, config.current_range_v, config.fsr_range_v)
    ai = tuple(
        AiChannelPlan(f"{dev}/{phys}", name, -r, r)
        for phys, name, r in zip(config.ai_channels, config.channel_names, ranges)
    )
    bits = line_bits(sweep.line_names)
    do_channel = ",".join(f"{dev}/{name}" for name in sweep.line_names)
    words = pack_lines(np.tile(sweep.lines, (n_sweeps, 1)), bits)
    # an idle tail, so the board is left with every chip inhibited and no current commanded:
    # a timed task holds its last value, and a DC current through the fluid electrolyses it
    idle = words[-1] | pack_lines(np.array([[False, False] + [True] * (len(bits) - 2)]), bits)[0]
    ao = np.concatenate([ao, np.zeros(IDLE_TAIL_SAMPLES)])
    words = np.concatenate([words, np.full(IDLE_TAIL_SAMPLES, idle, dtype=np.uint32)])
    total = n + IDLE_TAIL_SAMPLES
    return NiTaskPlan(
        dev,
        config.rate_hz,
        total,
        n,
        f"/{dev}/ai/SampleClock",
        ai,
        f"{dev}/{config.ao_channel}",
        10.0,
        ao,
        do_channel,
        words,
        config.to_physical,
        total / config.rate_hz + timeout_margin_s,
    )


def import_nidaqmx():
    """The nidaqmx module, or a HardwareError that says how to install it."""
    try:
        return importlib.import_module("nidaqmx")
    except ImportError as exc:
        raise HardwareError(
            "the NI backend needs the nidaqmx package and the NI-DAQmx driver: "
            "pip install 'neatskin-rig[ni]' and install NI-DAQmx from ni.com "
            "(or run with --daq simulated)"
        ) from exc


class NiDAQ(Daq):
    """The NI USB-6229 (or any DAQmx device with AI, AO and a clocked port0)."""

    def __init__(self, config: DaqConfig = DaqConfig()) -> None:
        self.nidaqmx = import_nidaqmx()
        self.config = config
        self.configure(config)

    def configure(self, config: DaqConfig) -> None:
        self.config = config
        try:
            names = [d.name for d in self.nidaqmx.system.System.local().devices]
        except Exception as exc:  # driver missing or broken: nidaqmx raises its own types
            raise HardwareError(f"NI-DAQmx did not answer: {exc}") from exc
        if config.device not in names:
            raise HardwareError(
                f"no NI device '{config.device}' answers (found: {', '.join(names) or 'none'}); "
                "plug in the USB-6229 or set the device name"
            )

    def acquire(
        self, sweep: Sweep, n_sweeps: int = 1, *, rng: np.random.Generator | None = None, start_time_s: float = 0.0
    ) -> Acquisition:
        plan = plan_acquisition(self.config, sweep, n_sweeps, start_time_s)
        try:
            raw = apply_plan(self.nidaqmx, plan)
        except HardwareError:
            raise
        except Exception as exc:
            raise HardwareError(f"the NI acquisition failed: {exc}") from exc
        start = int(round(start_time_s * self.config.rate_hz))
        samples = raw[:, : plan.n_data].T * plan.to_physical
        return Acquisition(samples, start + np.arange(plan.n_data, dtype=np.int64), self.config, n_sweeps)


def apply_plan(nidaqmx, plan: NiTaskPlan) -> np.ndarray:
    """Run the planned tasks; returns AI volts (3, samples). AO and DO start first, slaved to the AI clock."""
    from nidaqmx.constants import AcquisitionType, LineGrouping, TerminalConfiguration
    from nidaqmx.stream_readers import AnalogMultiChannelReader
    from nidaqmx.stream_writers import AnalogSingleChannelWriter, DigitalSingleChannelWriter

    finite = AcquisitionType.FINITE
    with nidaqmx.Task() as ai, nidaqmx.Task() as ao, nidaqmx.Task() as do:
        for ch in plan.ai:
            ai.ai_channels.add_ai_voltage_chan(
                ch.physical,
                name_to_assign_to_channel=ch.name,
                terminal_config=getattr(TerminalConfiguration, ch.terminal),
                min_val=ch.min_v,
                max_val=ch.max_v,
            )
        ai.timing.cfg_samp_clk_timing(plan.rate_hz, sample_mode=finite, samps_per_chan=plan.n_samples)
        ao.ao_channels.add_ao_voltage_chan(plan.ao_channel, min_val=-plan.ao_range_v, max_val=plan.ao_range_v)
        ao.timing.cfg_samp_clk_timing(
            plan.rate_hz, source=plan.clock_source, sample_mode=finite, samps_per_chan=plan.n_samples
        )
        do.do_channels.add_do_chan(plan.do_channel, line_grouping=LineGrouping.CHAN_FOR_ALL_LINES)
        do.timing.cfg_samp_clk_timing(
            plan.rate_hz, source=plan.clock_source, sample_mode=finite, samps_per_chan=plan.n_samples
        )
        AnalogSingleChannelWriter(ao.out_stream, auto_start=False).write_many_sample(
            np.ascontiguousarray(plan.ao_data_v, dtype=np.float64)
        )
        DigitalSingleChannelWriter(do.out_stream, auto_start=False).write_many_sample_port_uint32(
            np.ascontiguousarray(plan.do_data, dtype=np.uint32)
        )
        ao.start()
        do.start()
        ai.start()
        data = np.empty((len(plan.ai), plan.n_samples), dtype=np.float64)
        AnalogMultiChannelReader(ai.in_stream).read_many_sample(data, plan.n_samples, timeout=plan.timeout_s)
        ao.wait_until_done(timeout=plan.timeout_s)
        do.wait_until_done(timeout=plan.timeout_s)
    return data

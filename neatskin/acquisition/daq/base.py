"""The DAQ interface every backend implements: its configuration value, the Acquisition it returns, and the Daq base class.

One sample clock drives everything: sample n of an acquisition is at sample_index[n] /
rate_hz, so the pair live on it is known from the sweep's line table by index, not by a timer.

Channels (in this order): voltage_v (across the live pair), current_a (through it),
fsr_v (the force-sensing resistor's divider output). The AI reads volts; `voltage_gain`
(AI volts per volt across the pair) and `current_gain_v_per_a` (the galvanostat's current
monitor) convert them to the physical units stored here. The defaults fit the paper's rig on
the NI USB-6229's +-10 V range, through the paper's MAX4052 mux board at +-8 V: 0.2 mA, as the protocols (the
paper's 2 mA would pass the mux rails on every pair above ~3.8 kohm, 0.5 mA on ~2 % of the pressed ones;
docs/acquisition.md, "Electrical limits").

The mux rails (`rail_positive_v`, `rail_negative_v`, from the wiring's [electrical]) bound what the rig can
read: the switch node on the galvanostat's side of the mux sits at i x (R + mux_series_ohm), mux_series_ohm
= 2 R_on + the R_on mismatch (the wiring's worst case). Where that would pass a rail the switch's protection
diodes clamp it: the galvanostat's current no longer all flows through the skin, so V / I is wrong and the
demodulator flags the pair CLIPPED (neatskin.acquisition.demod).
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import numpy as np

from neatskin.errors import ConfigError, Problem

CHANNELS = ("voltage_v", "current_a", "fsr_v")


def _is_number(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


@dataclass(frozen=True)
class DaqConfig:
    rate_hz: float = 10_000.0
    amplitude_a: float = 0.0002  # excitation peak current: 0.2 mA keeps the paper's pressed skin in the rails
    frequency_hz: float = 1_000.0
    voltage_range_v: float = 10.0  # AI range (+-) of each channel
    current_range_v: float = 10.0
    fsr_range_v: float = 10.0
    voltage_gain: float = 0.5  # AI volts per volt across the pair (isolation amplifier / monitor divider)
    current_gain_v_per_a: float = 1_000.0  # galvanostat current monitor: 1 V per mA
    ao_v_per_a: float = 1_000.0  # galvanostat control input: AO volts per amp commanded
    compliance_v: float = 50.0  # the galvanostat's output voltage limit (HA-151B class; set your instrument's)
    adc_bits: int = 16
    # the mux board between the galvanostat and the skin (wiring [electrical]; MAX4052 at +-8 V, datasheet
    # maxima: assumed). rig/assembly.daq_config passes the protocol's wiring.
    rail_positive_v: float = 8.0
    rail_negative_v: float = -8.0
    mux_series_ohm: float = 210.0  # 2 x 100 ohm R_on + 10 ohm mismatch, in series with the pair
    channel_names: tuple[str, ...] = CHANNELS
    device: str = "Dev1"
    ai_channels: tuple[str, ...] = ("ai0", "ai1", "ai2")
    ao_channel: str = "ao0"

    def __post_init__(self) -> None:
        problems = []
        for name in (
            "rate_hz",
            "amplitude_a",
            "frequency_hz",
            "voltage_range_v",
            "current_range_v",
            "fsr_range_v",
            "voltage_gain",
            "current_gain_v_per_a",
            "ao_v_per_a",
            "compliance_v",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                problems.append(
                    Problem(f"{name} must be a positive number, got {value!r}", "<daq config>", name, f"set {name} > 0")
                )
        if not problems and self.frequency_hz * 2 >= self.rate_hz:
            problems.append(
                Problem(
                    f"excitation {self.frequency_hz} Hz is not below Nyquist of {self.rate_hz} Hz",
                    "<daq config>",
                    "frequency_hz",
                    "sample at least 4x faster than the excitation",
                )
            )
        for name, ok, rule in (
            ("rail_positive_v", _is_number(self.rail_positive_v) and self.rail_positive_v > 0, "> 0"),
            ("rail_negative_v", _is_number(self.rail_negative_v) and self.rail_negative_v < 0, "< 0"),
            ("mux_series_ohm", _is_number(self.mux_series_ohm) and self.mux_series_ohm >= 0, ">= 0"),
        ):
            if not ok:
                problems.append(
                    Problem(
                        f"{name} must be a number {rule}, got {getattr(self, name)!r}",
                        "<daq config>",
                        name,
                        f"set {name} {rule} (the wiring's [electrical])",
                    )
                )
        if len(self.channel_names) != 3 or len(self.ai_channels) != 3:
            problems.append(
                Problem(
                    "three channels are needed: voltage, current, FSR",
                    "<daq config>",
                    "channel_names",
                    "name three channels and three AI inputs",
                )
            )
        if not isinstance(self.adc_bits, int) or not 8 <= self.adc_bits <= 24:
            problems.append(
                Problem(
                    f"adc_bits must be 8..24, got {self.adc_bits!r}",
                    "<daq config>",
                    "adc_bits",
                    "set adc_bits = 16 for the USB-6229",
                )
            )
        if not problems and self.amplitude_a * self.ao_v_per_a > 10.0:
            problems.append(
                Problem(
                    f"the excitation needs {self.amplitude_a * self.ao_v_per_a:.3g} V on the AO, beyond +-10 V",
                    "<daq config>",
                    "amplitude_a",
                    "lower amplitude_a or the galvanostat's ao_v_per_a",
                )
            )
        if problems:
            raise ConfigError(problems=problems)

    @property
    def voltage_limit_v(self) -> float:
        """Largest voltage across the pair the AI can read without clipping."""
        return self.voltage_range_v / self.voltage_gain

    @property
    def rail_v(self) -> float:
        """The nearer mux rail (V): the sine's peak reaches both signs."""
        return min(self.rail_positive_v, -self.rail_negative_v)

    @property
    def rail_ohm(self) -> float:
        """The largest pair R whose switch node stays inside the rails at the sine's peak:
        rail_v / amplitude_a - mux_series_ohm. Above it the mux clamps and the reading is CLIPPED."""
        return self.rail_v / self.amplitude_a - self.mux_series_ohm

    @property
    def node_lsb_v(self) -> float:
        """One ADC step of the mux's switch node as the rig reads it, v + i x mux_series_ohm (V)."""
        return float(
            self.lsb_ai_v[0] * self.to_physical[0] + self.mux_series_ohm * self.lsb_ai_v[1] * self.to_physical[1]
        )

    @property
    def readable_ohm(self) -> float:
        """The largest pair R the rig reads as a value: within the galvanostat's compliance, the AI's reach and
        the mux rails at the sine's peak. Above it the reading is flagged (CLIPPED, or OPEN_CIRCUIT too for a
        pair cut off) and recorded as no value (+inf), as a cut pair's."""
        return min(self.compliance_v / self.amplitude_a, self.voltage_limit_v / self.amplitude_a, self.rail_ohm)

    @property
    def current_limit_a(self) -> float:
        return self.current_range_v / self.current_gain_v_per_a

    @property
    def lsb_ai_v(self) -> np.ndarray:
        """One ADC step in AI volts, per channel (3,)."""
        ranges = np.array([self.voltage_range_v, self.current_range_v, self.fsr_range_v])
        return 2.0 * ranges / 2**self.adc_bits

    @property
    def to_physical(self) -> np.ndarray:
        """Factors from AI volts to stored units, per channel (3,)."""
        return np.array([1.0 / self.voltage_gain, 1.0 / self.current_gain_v_per_a, 1.0])

    @property
    def samples_per_period(self) -> float:
        return self.rate_hz / self.frequency_hz


@dataclass(frozen=True, eq=False)
class Acquisition:
    """Samples of n_sweeps whole, consecutive sweeps: (samples, 3) in CHANNELS order, with their global indices."""

    samples: np.ndarray = field(repr=False)  # (samples, 3): voltage_v, current_a, fsr_v
    sample_index: np.ndarray = field(repr=False)  # (samples,) int64, global sample-clock index
    config: DaqConfig
    n_sweeps: int = 1

    def __post_init__(self) -> None:
        if self.samples.ndim != 2 or self.samples.shape[1] != 3:
            raise ValueError(f"samples must be (samples, 3), got {self.samples.shape}")
        if self.sample_index.shape != (self.samples.shape[0],):
            raise ValueError("one sample index per sample is needed")

    @property
    def rate_hz(self) -> float:
        return self.config.rate_hz

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def times_s(self) -> np.ndarray:
        return self.sample_index / self.config.rate_hz

    @property
    def voltage_v(self) -> np.ndarray:
        return self.samples[:, 0]

    @property
    def current_a(self) -> np.ndarray:
        return self.samples[:, 1]

    @property
    def fsr_v(self) -> np.ndarray:
        return self.samples[:, 2]


class Daq(abc.ABC):
    """A DAQ backend: configure once, acquire whole sweeps, close. Usable as a context manager."""

    config: DaqConfig

    def configure(self, config: DaqConfig) -> None:
        self.config = config

    @abc.abstractmethod
    def acquire(
        self, sweep, n_sweeps: int = 1, *, rng: np.random.Generator | None = None, start_time_s: float = 0.0
    ) -> Acquisition:
        """Run n_sweeps of the sweep's line table on the sample clock; return every sample."""

    def close(self) -> None:  # noqa: B027 - a backend with nothing to release need not override it
        """Release the device (default: nothing to release)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

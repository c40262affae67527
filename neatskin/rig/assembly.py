"""The rig a campaign runs against, as the runner sees it (`Rig`), and the real rig's builder.

Both builders (`build_real_rig` here, neatskin.rig.dryrig's `build_dry_rig` for the simulated printer and
skin) take the campaign's `Plan` (neatskin.rig.plan) and return a `Rig` whose driver, recorder and clock the
runner uses the same way. The real rig never imports a simulator: the runner imports the dry rig's module only
for a dry run, and the NI backend (the one module that imports nidaqmx) only when a real run opens it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Protocol

from neatskin.acquisition.daq.base import Daq, DaqConfig
from neatskin.acquisition.fsr import FsrModel
from neatskin.acquisition.record import Recorder
from neatskin.errors import ConfigError, HardwareError
from neatskin.marlin.driver import DriverConfig, MarlinDriver
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.rig.recorder import ThreadedRecorder

DAQ_KINDS = ("simulated", "ni")
# lines a campaign's driver may have in flight, real rig and dry run alike: more than one only when the firmware
# names its lines (`ok N.. P.. B..`, Marlin's ADVANCED_OK); a stock Marlin without it gets one line at a time
CAMPAIGN_MAX_IN_FLIGHT = 4


class Driver(Protocol):
    """The printer as the press loop drives it (neatskin.marlin.driver.MarlinDriver, on a real port or the
    simulated printer's pty): a program's lines in order, exactly once each, returning when the last one ran.
    Only what the press loop uses: what send_lines returns is not read."""

    def send_lines(self, lines: Iterable[str], *, source: str = ...) -> object: ...


# files a rig derives from the campaign it ran once every press is on disk: name -> write(folder) -> path
DerivedFiles = Mapping[str, Callable[[Path], Path]]


@dataclass
class Rig:
    """What the runner uses of a rig, real or dry alike: it never asks which one it has."""

    kind: str  # "dry-run" | "real": recorded in the manifest and the rows, never branched on
    driver: Driver
    recorder: Recorder  # neatskin.acquisition.record: end() gives a PendingPress (done, or the skin worker's ticket)
    fsr_model: FsrModel  # the FSR's divider, a value type: what labels a press from its voltage
    description: dict[str, Any]
    closers: list[Callable[[], None]] = field(default_factory=list)
    derived_files: DerivedFiles = field(default_factory=dict)  # the dry run's physical limit
    # how durable a press is before the next: the real rig fsyncs every press, one a part; a dry run's presses
    # are recomputed identically from (seed, press_id), so a kill may lose its batch and resume presses it again
    fsync: bool = True
    batch_presses: int = 1

    def close(self) -> None:
        for close in reversed(self.closers):
            try:
                close()
            except Exception:  # closing must not mask the error that got us here
                pass


def open_daq(kind: str, config: DaqConfig = DaqConfig(), **kwargs: Any) -> Daq:
    """A configured backend by name. kwargs go to SimulatedDAQ (pair_resistance_ohm, force_n, noise, fsr, ...);
    the NI backend (HardwareError if nidaqmx or the device is missing) takes none."""
    if kind == "simulated":
        from neatskin.sim.daq import SimulatedDAQ  # here: a real run never imports the simulator

        if "pair_resistance_ohm" not in kwargs:
            raise ConfigError(
                "the simulated DAQ needs pair_resistance_ohm(times_s) -> (times, pairs)",
                field="pair_resistance_ohm",
                fix="pass the skin model's pair resistance callable",
            )
        return SimulatedDAQ(config, **kwargs)
    if kind == "ni":
        if kwargs:
            raise ConfigError(
                f"the NI backend takes no {', '.join(sorted(kwargs))}", field="daq", fix="pass only a DaqConfig"
            )
        from neatskin.acquisition.daq.nidaqmx_backend import NiDAQ  # imports nidaqmx, an optional extra

        return NiDAQ(config)
    raise ConfigError(f"unknown DAQ kind {kind!r}", field="daq", fix=f"use one of {', '.join(DAQ_KINDS)}")


def daq_config(protocol: CampaignProtocol) -> DaqConfig:
    """The DAQ settings of a protocol, its electrical limits included (ADC range, voltage gain, compliance, and the
    wiring's mux rails with the switches' worst-case series resistance), so a dry run clips where the protocol's
    rig would and the real rig's demodulator flags a reading the mux clamped."""
    e = protocol.wiring.electrical
    return DaqConfig(
        rate_hz=protocol.acquisition.rate_hz,
        amplitude_a=protocol.excitation.amplitude_a,
        frequency_hz=protocol.excitation.frequency_hz,
        voltage_range_v=protocol.acquisition.adc_range_v,
        voltage_gain=protocol.acquisition.voltage_gain,
        compliance_v=protocol.excitation.compliance_v,
        rail_positive_v=e.supply_positive_v,
        rail_negative_v=e.supply_negative_v,
        mux_series_ohm=2 * e.r_on_ohm + e.r_on_mismatch_ohm,
    )


def open_printer(
    protocol: CampaignProtocol,
    port: str,
    closers: list[Callable[[], None]],
    baud_rate: int | None = None,
    connect_timeout_s: float = 5.0,
    wire_log: str | PathLike[str] | None = None,
) -> MarlinDriver:
    """The campaign's driver on a real port, connected; its close goes on `closers` as soon as it is open.
    The profile's RX_BUFFER_SIZE bounds the bytes in flight (a stock board loses what overflows its ring)."""
    driver = MarlinDriver.open(
        port,
        baud_rate or protocol.printer.baud_rate,
        wire_log=wire_log,
        config=DriverConfig(max_in_flight=CAMPAIGN_MAX_IN_FLIGHT),
        rx_buffer_size=protocol.printer.rx_buffer_size,
    )
    closers.append(driver.close)
    driver.connect(boot_timeout_s=connect_timeout_s)
    return driver


@contextmanager
def closed_on_failure(closers: list[Callable[[], None]], what: str) -> Iterator[None]:
    """Opening a rig's devices: on any failure close what was opened (`closers`, in reverse) before the error
    leaves; a HardwareError passes as it is, anything else becomes one HardwareError "cannot open {what}"."""
    try:
        yield
    except HardwareError:
        for close in reversed(closers):
            close()
        raise
    except Exception as exc:
        for close in reversed(closers):
            close()
        raise HardwareError(f"cannot open {what}: {exc}") from exc


def build_real_rig(
    protocol: CampaignProtocol,
    plan: Plan,
    *,
    port: str,
    daq_kind: str = "ni",
    baud_rate: int | None = None,
    connect_timeout_s: float = 5.0,
    wire_log: str | PathLike[str] | None = None,
) -> Rig:
    """The printer on a serial port and the DAQ; errors are HardwareErrors raised before any motion.
    The simulated DAQ on a real port is neatskin.rig.hilrig's (the runner builds it there)."""
    closers: list[Callable[[], None]] = []
    # the printer first: a port that does not answer is the commonest set-up mistake
    with closed_on_failure(closers, f"the rig (printer on {port}, DAQ {daq_kind})"):
        driver = open_printer(protocol, port, closers, baud_rate, connect_timeout_s, wire_log)
        daq = open_daq(daq_kind, daq_config(protocol))
        closers.append(daq.close)
    recorder = ThreadedRecorder(
        daq,
        plan.sweep,
        method=protocol.acquisition.demodulation,
        window=protocol.acquisition.window,
        fsr_enabled=protocol.fsr_enabled,
        keep_waveforms=protocol.record_waveforms,
    )
    description = {"kind": "real", "printer": port, "daq": daq_kind}
    return Rig("real", driver, recorder, FsrModel(), description, closers)

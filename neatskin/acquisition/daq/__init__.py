"""DAQ backends behind one interface (daq.base.Daq): simulated, and NI-DAQmx imported only when asked for.

    daq = open_daq("simulated", config, pair_resistance_ohm=..., force_n=..., noise=...)
    daq = open_daq("ni", config)          # HardwareError if nidaqmx or the device is missing
"""

from __future__ import annotations

from neatskin.errors import ConfigError
from neatskin.acquisition.daq.base import CHANNELS, Acquisition, Daq, DaqConfig

KINDS = ("simulated", "ni")


def open_daq(kind: str, config: DaqConfig = DaqConfig(), **kwargs) -> Daq:
    """A configured backend. kwargs go to SimulatedDAQ (pair_resistance_ohm, force_n, noise, fsr, ...)."""
    if kind == "simulated":
        from neatskin.acquisition.daq.simulated import SimulatedDAQ

        if "pair_resistance_ohm" not in kwargs:
            raise ConfigError("the simulated DAQ needs pair_resistance_ohm(times_s) -> (times, pairs)",
                              field="pair_resistance_ohm", fix="pass the skin model's pair resistance callable")
        return SimulatedDAQ(config, **kwargs)
    if kind == "ni":
        if kwargs:
            raise ConfigError(f"the NI backend takes no {', '.join(sorted(kwargs))}", field="daq",
                              fix="pass only a DaqConfig")
        from neatskin.acquisition.daq.nidaqmx_backend import NiDAQ

        return NiDAQ(config)
    raise ConfigError(f"unknown DAQ kind {kind!r}", field="daq", fix=f"use one of {', '.join(KINDS)}")


__all__ = ["CHANNELS", "Acquisition", "Daq", "DaqConfig", "KINDS", "open_daq"]

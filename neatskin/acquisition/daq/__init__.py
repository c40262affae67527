"""The DAQ interface (daq.base.Daq) and the NI-DAQmx backend, imported only when asked for.

The simulated DAQ lives with the other simulated devices in `neatskin.sim.daq`; the rig
assembly (`neatskin.rig.assembly.open_daq`) picks a backend by name.
"""

from __future__ import annotations

from neatskin.acquisition.daq.base import CHANNELS, Acquisition, Daq, DaqConfig

__all__ = ["CHANNELS", "Acquisition", "Daq", "DaqConfig"]

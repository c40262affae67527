"""DAQ backends behind one interface: simulated and NI-DAQmx."""

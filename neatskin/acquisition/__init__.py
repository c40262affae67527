"""Acquisition: mux board and switching sequence, DAQ backends, demodulation, FSR press detection."""

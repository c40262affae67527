"""Marlin host protocol: serial driver and simulated printer."""

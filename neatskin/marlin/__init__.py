"""The host side of Marlin's serial protocol: line protocol, driver, replies grammar, wire log."""

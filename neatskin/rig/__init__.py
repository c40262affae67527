"""The apparatus: Marlin driver, simulated printer, simulated skin, and the campaign runner that composes them."""

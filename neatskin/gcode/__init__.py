"""G-code: press positions, press programs, Marlin G-code text, parsing, bounds, motion-time estimates."""

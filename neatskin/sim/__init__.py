"""The simulated devices of the dry run, behind the same interfaces as the real ones.

firmware (the Marlin firmware model: commands, homing, motion, replies), intake (its serial side: the
receive ring, line numbers, checksums, resends, the command queue), clock (virtual or scaled time), motion
(the printer's trajectory), printer (that firmware served on a real pseudo-terminal), pty,
faults, scripted (scripted serial peers for tests), daq (the simulated DAQ sampling a skin),
noise (its imperfections), moments (the features path's statistics), dryprobe (the skin and force along
the printer's trajectory), recorder (a press's acquisition from it), deferred (a press whose estimates
come later), skinworker (those estimates in a second process), pressestimator (what that process computes
per press), dryscene (the dry run's skin, probe, DAQ and per-press conditions, built from the DryScene the
rig hands over), cli (`neatskin sim printer`). Uses skin, gcode and acquisition; never rig.
"""

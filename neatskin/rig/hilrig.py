"""Hardware in the loop: a real printer on a serial port (or the real firmware, or the simulated printer on a pty)
pressing the simulated skin, read by the simulated DAQ (`campaign run PROTOCOL --port PORT --daq simulated`).

A technician checks a printer's motion before the DAQ is wired. The probe follows what crosses the serial line
only (neatskin.sim.linetrack.LineTracker: the commanded program on the firmware's machine model, confirmed by the
printer's acknowledgements and its M114 reports); the skin, DAQ and per-press conditions are the dry run's
(neatskin.sim.dryscene), so a press records what a dry run of the same program records. The rig is "real" (its
printer is) and its description says the DAQ and skin were simulated.
"""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike

from neatskin.rig.assembly import Rig, closed_on_failure, open_printer
from neatskin.rig.dryrig import dry_scene, simulated_recorder
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.sim.dryscene import dry_daq, dry_probe, dry_skin
from neatskin.sim.linetrack import LineTracker


def build_hil_rig(
    protocol: CampaignProtocol,
    plan: Plan,
    *,
    port: str,
    baud_rate: int | None = None,
    connect_timeout_s: float = 5.0,
    wire_log: str | PathLike[str] | None = None,
) -> Rig:
    """The printer on `port` (HardwareError before any motion when it does not answer), the simulated skin and
    DAQ following the printer's commanded, acknowledged and M114-checked motion."""
    closers: list[Callable[[], None]] = []
    with closed_on_failure(closers, f"the printer on {port} (DAQ simulated)"):
        driver = open_printer(protocol, port, closers, baud_rate, connect_timeout_s, wire_log)
    tracker = LineTracker(driver, protocol.printer)
    dry = dry_scene(protocol, plan)
    scene = dry.scene
    skin = dry_skin(dry)
    probe = dry_probe(dry, skin, tracker.segments)
    daq = dry_daq(dry, probe)
    recorder = simulated_recorder(protocol, plan, dry, daq, probe, tracker.now_s)
    closers.append(recorder.close)  # its FSR noise thread ends with the rig, as the dry rig's does
    description = {
        "kind": "real",
        "printer": port,
        "daq": "simulated",
        "skin": {
            "simulated": True,
            "fidelity": scene.fidelity,
            "signal": scene.signal,
            "noise": scene.noise,
            "preset": getattr(scene, "preset", "ideal"),
        },
        "motion": "the commanded program on the firmware's machine model, checked by M114 after every M400",
    }
    return Rig("real", tracker, recorder, daq.fsr, description, closers)

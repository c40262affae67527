"""What the simulated Marlin believes of its axes and how the probe really moves: homing (G28 as G28.cpp, with
M206's home offset), moves and their E, the soft endstops (M211) and the quick stop (M410), on the one G-code machine
model (gcode.machine) and the probe's timeline (sim.motion).

As stock Marlin (built without NO_MOTION_BEFORE_HOMING), a move before homing runs from where the firmware believes
the head is (zeros at boot), unclamped on the axes not homed, and the probe moves by the same steps from where it
really is (`_frame_mm`: real minus believed, per axis; zero once the axis is homed without a home offset, until
steps are lost against the frame). Positions are 32-bit, as the firmware's (sim.intake reads X, Y, Z, E as strtof).
sim.firmware's MarlinCore builds on this class and runs the commands.
"""

from __future__ import annotations

import collections
import math

from neatskin.gcode.machine import Machine, MaybeXyz, Move, Xyz
from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile
from neatskin.sim.clock import ScaledClock, VirtualClock
from neatskin.sim.extruder import COLD_EXTRUSION, Extruder
from neatskin.sim.intake import LineIntake
from neatskin.sim.motion import Timeline
from neatskin.sim.settings import Settings, f32

__all__ = ["MOVES", "Belief"]

MOVES = frozenset({"G0", "G1", "G2", "G3"})  # an arc (G2/G3) goes along its chord: the end is right, the path not


class Belief(LineIntake):
    """The firmware's belief and the probe's motion; the state is MarlinCore's (it sets every attribute below)."""

    profile: PrinterProfile
    clock: VirtualClock | ScaledClock
    machine: Machine
    timeline: Timeline
    homed: list[bool]
    soft_endstops: bool
    no_motion_before_homing: bool
    settings: Settings
    extruder: Extruder
    clip_events: collections.deque[tuple[float, str, MaybeXyz, MaybeXyz]]
    _frame_mm: list[float]
    _head_ready: float | None

    def _set_soft_endstops(self, on: bool) -> None:
        """M211: the machine clamps native targets on homed axes to the soft limits while they are on (and to
        nothing while they are off: the real firmware, `M211 S0` then `G1 X-5`, reports X:-5.00)."""
        self.soft_endstops = on
        self._apply_limits()

    def _travel_mm(self, soft: bool) -> tuple[Xyz, Xyz]:
        """The bed's travel (lo, hi), within the soft limits when `soft`: the profile's boxes, built once."""
        return self.profile.soft_box_mm if soft else self.profile.travel_box_mm

    def _apply_limits(self) -> None:
        # Marlin's apply_motion_limits clamps only the axes it has homed (motion.cpp: `if (axis_was_homed(..))`)
        lo, hi = self._travel_mm(True)
        h = self.homed if self.soft_endstops else (False, False, False)
        self.machine.limits_mm = (
            (lo[0] if h[0] else -math.inf, lo[1] if h[1] else -math.inf, lo[2] if h[2] else -math.inf),
            (hi[0] if h[0] else math.inf, hi[1] if h[1] else math.inf, hi[2] if h[2] else math.inf),
        )

    @property
    def homed_all(self) -> bool:
        h = self.homed
        return h[0] and h[1] and h[2]

    def _refuses_motion(self) -> bool:
        """NO_MOTION_BEFORE_HOMING: Marlin's G0/G1 does nothing but say so while an axis is not homed."""
        return self.no_motion_before_homing and not self.homed_all

    def _home(self, axes: tuple[int, ...], raise_mm: float | None = None) -> float:
        """G28 as Marlin's G28.cpp; when it is done. The machine model (gcode.machine `Machine.home`) says what
        the firmware does: before homing X or Y, Z rises by the profile's homing clearance (relative while Z is
        not homed, to that height once it is; never down); the axes go home; once Z is homed it moves to the
        post-homing height (down too). The native build: G0 Z5, G28 X -> Z:10.00; a full G28 -> Z:5.00; G1 Z2,
        G28 Y -> Z:5.00; G1 Z20, G28 Y -> Z:20.00; G28 X R3 -> Z:23.00 (R: relative); G28 Y R0 -> no raise.
        _reply prints the position. The profile's `homing_time_s` is
        a whole G28 as measured, raises included: the homing takes what they leave."""
        now = self.clock.now()
        tl = self.timeline
        # M206's home offset: an axis homed is believed to be at its home plus the offset (set_axis_is_at_home), so
        # the probe, at the home itself, is the offset away from where the firmware believes it (_frame_mm)
        offset = self.settings.home_offset_mm
        self.machine.home_mm = tuple(h + o for h, o in zip(self.profile.soft_min_mm, offset))  # type: ignore[assignment]
        home = self.machine.home(axes, raise_mm)
        if home.rise is not None:
            self._queue_move(home.rise, "G28")
        for i in home.axes:
            self._frame_mm[i] = -offset[i]
        self._apply_limits()
        # the axes homed go home; the others stay where the probe is
        homed_end = home.after.start_mm if home.after is not None else home.end_mm
        frame = self._frame_mm
        end = tuple(
            h + frame[i] if i in home.axes and h is not None else p
            for i, (h, p) in enumerate(zip(homed_end, tl.end_mm))
        )
        tl.add_homing(now, end, home.homing_s)  # type: ignore[arg-type]
        if home.after is not None:
            self._queue_move(home.after, "G28")
        return tl.end_s

    def _move(self, line: GcodeLine) -> None:
        e = line.get("E")
        # an arc's segments each say it on the real firmware; the simulated arc (one chord) says nothing
        if isinstance(e, float) and self.extruder.move(e, self.settings.steps_per_mm[3]) and line.code in ("G0", "G1"):
            self._emit(COLD_EXTRUSION)
        if line.code in ("G2", "G3"):  # the arc's chord, to the same end
            line = GcodeLine("G1", {k: v for k, v in line.params.items() if k in "XYZF"}, raw=line.raw)
        event = self.machine.step(line)
        self.machine.position_mm = [None if p is None else f32(p) for p in self.machine.position_mm]  # 32-bit
        self._queue_move(event, line.raw)  # type: ignore[arg-type]

    def _round_belief(self) -> None:
        """Marlin's positions and offsets are 32-bit: the machine model's result (of 32-bit numbers: sim.intake)
        rounds to what the firmware computes, so M114 prints what it prints (-0.335 through a G92 offset)."""
        machine = self.machine
        machine.position_mm = [None if p is None else f32(p) for p in machine.position_mm]
        machine.offset_mm = [f32(o) for o in machine.offset_mm]

    def _quick_stop(self) -> None:
        """M410 (quickstop_stepper): the planned motion is dropped and the steppers stop where they are, which the
        firmware then believes (set_current_from_steppers); a queued command waiting for the motion goes on."""
        now = self.clock.now()
        here = self.timeline.position_mm(now)
        self.timeline.teleport(now, here)
        position, frame = self.machine.position_mm, self._frame_mm
        for i in range(3):
            position[i] = here[i] - frame[i]
        if self.queue and self._head_ready is not None and (self.queue[0][2] in MOVES or self.queue[0][2] == "M400"):
            self._head_ready = now

    def _queue_move(self, event: Move, raw: str) -> None:
        """The probe's motion for a move the firmware believes it made."""
        assert event.duration_s is not None  # the machine starts at zeros: all known
        now = self.clock.now()
        if event.clamped:
            self.clip_events.append((now, raw, event.requested_mm, event.end_mm))
        frame = self._frame_mm
        if self.homed_all and self.soft_endstops and frame[0] == frame[1] == frame[2] == 0.0:
            self.timeline.add(now, event)  # the targets are clamped inside the bed: the probe is where it is believed
            return
        # not homed, or soft endstops off: the steppers step from where the probe is; a stop at the end of the
        # bed's travel loses steps (the firmware still believes the target)
        lo, hi = self._travel_mm(False)
        end = [min(max(e + f, a), b) for e, f, a, b in zip(event.end_mm, frame, lo, hi)]  # type: ignore[operator]
        for i in range(3):
            frame[i] = end[i] - event.end_mm[i]  # type: ignore[operator]
        self.timeline.add(now, event._replace(start_mm=self.timeline.end_mm, end_mm=(end[0], end[1], end[2])))

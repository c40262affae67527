"""The simulated printer's firmware: Marlin's command set, motion and replies, without any I/O.

`MarlinCore.receive(bytes)` takes what the host wrote (sim.intake: the receive ring, line numbers,
checksums, resends, the command queue); `step()` runs what can run now and says how long (in real
seconds) until something is due; `take_output()` gives the reply bytes. What it prints matches the
real firmware byte for byte where tests/test_marlin_real_vs_sim.py compares them (`\r\n` after M118
and the M111 echo, the banner, M115's capabilities, M114 zeros before homing, `Count` at the end of
the queued motion, M112 only as a command, nothing after a kill until a reset, moves before homing,
G28's Z raises and its position report, M211's report and its S0 that clamps nothing; in
tests/test_marlin_real_settings.py the settings commands of sim.settings, a bare M110's `Line: N`, M114's 32-bit
numbers and cold extrusion, sim.extruder's). Commands run
in order from a BUFSIZE-slot queue; moves go to a planner of `planner_buffer_size` slots (a full
planner delays the `ok`). As stock Marlin (built without NO_MOTION_BEFORE_HOMING), a move before
homing runs from where the firmware believes the head is (zeros at boot), unclamped on the axes not
homed, and the probe moves by the same steps from where it really is (`_frame_mm`: real minus
believed, per axis; zero once the axis is homed, until steps are lost against the frame);
`no_motion_before_homing=True` refuses it instead (`echo:Home XYZ First`, then `ok`), as a Marlin
built with that option. Time is a clock object (sim.clock): virtual (jumps to when the motion is
done; no sleeping) or scaled real time. Faults (faults.FaultConfig) are drawn from a seeded numpy
Generator. Its memory is bounded however long it runs: the latest `history_lines` executed commands
(and `executed_count` of them all) and the latest `keep_segments` moves (sim.motion.Timeline).
"""

from __future__ import annotations

import collections
import math

import numpy as np

from neatskin.gcode.machine import Machine, MaybeXyz, Move, Xyz, homing_request
from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import replies as R
from neatskin.sim.clock import ScaledClock, VirtualClock
from neatskin.sim.extruder import COLD_EXTRUSION, Extruder, position_report
from neatskin.sim.faults import FaultConfig
from neatskin.sim.firmware_texts import banner_lines, m115_lines
from neatskin.sim.housekeeping import CODES as HOUSEKEEPING
from neatskin.sim.housekeeping import TEMPERATURES, Housekeeping
from neatskin.sim.intake import LineIntake
from neatskin.sim.motion import Timeline
from neatskin.sim.settings import CODES as SETTINGS
from neatskin.sim.settings import Settings, f32, marlin_float, settings_report

__all__ = ["MarlinCore", "ScaledClock", "VirtualClock"]

_MOVES = frozenset({"G0", "G1", "G2", "G3"})  # an arc (G2/G3) goes along its chord: the end is right, the path not
_MODES = frozenset({"G90", "G91", "M82", "M83"})
_SILENT = frozenset({"G0", "G1", "G4", "M400", "M999", "M111"})
_OK = b"ok\n"
QUICK_STOP_HOLD_S = 1.0
# (M84/M18 among them: stock Marlin keeps the axes homed when it turns the steppers off, HOME_AFTER_DEACTIVATE off)
_QUIET = frozenset(
    {"G21", "G90", "G91", "M17", "M18", "M82", "M83", "M84", "M104", "M106", "M107", "M108", "M117", "M140", "M220"}
    | {"M221", "M410"}
    # M109/M190 wait for a heater to reach its target: the simulated heaters stay at the room's temperature, so a
    # target at or below it (S0 in slicers' start code: the real firmware answers a plain ok) is reached at once
    | {"M109", "M190"}
)


class MarlinCore(LineIntake):
    def __init__(
        self,
        profile: PrinterProfile,
        *,
        seed: int = 0,
        faults: FaultConfig = FaultConfig(),
        clock=None,
        advanced_ok: bool = False,
        marlin_version: str = "2.1",
        ok_after_resend: bool = True,
        no_motion_before_homing: bool = False,
        bufsize: int = 4,
        rx_buffer_size: int | None = None,
        keepalive_s: float = 2.0,
        history_lines: int = 10_000,
        keep_segments: int = 4096,
    ) -> None:
        super().__init__(
            faults,
            np.random.default_rng(seed),
            marlin_version=marlin_version,
            ok_after_resend=ok_after_resend,
            bufsize=bufsize,
            rx_buffer_size=rx_buffer_size,
        )
        self.profile = profile
        self.clock = clock or VirtualClock()
        self._virtual = isinstance(self.clock, VirtualClock)
        self.advanced_ok = advanced_ok
        self.no_motion_before_homing = no_motion_before_homing
        self.echo_commands = False  # M111 S1
        self.keepalive_s = keepalive_s
        self.timeline = Timeline(profile, tuple(profile.park_mm), keep_segments)
        # bounded, so memory stays flat as a campaign grows: the latest lines, and a count of them all
        self.executed: collections.deque[tuple[int | None, str]] = collections.deque(maxlen=history_lines)
        self.executed_count = 0
        self.clip_events: collections.deque[tuple[float, str, MaybeXyz, MaybeXyz]] = collections.deque(
            maxlen=history_lines
        )
        self.resets = 0
        self._plain_ok = not (faults.drop_ok or faults.duplicate) and R.OK == "ok"
        self._boot()

    # ---- state ----------------------------------------------------------------------------

    def _boot(self) -> None:
        self._clear_intake()
        # the one G-code machine model (gcode.machine): native position, G92 offsets, modes: what the firmware
        # believes (zeros at boot, as Marlin); the timeline is where the probe is, _frame_mm the difference
        self.machine = Machine(
            self.profile,
            start_mm=(0.0, 0.0, 0.0),
            feed_mm_s=self.profile.travel_feed_mm_s,
            homing_time_s=self.profile.homing_time_s,
        )
        self.homed = self.machine.homed  # which axes G28 homed: the machine's (G28's Z rise depends on it)
        self._frame_mm = list(self.timeline.end_mm)
        self._set_soft_endstops(True)
        self.halted = False
        self._head_ready: float | None = None
        self._last_busy = self.clock.now()
        self.echo_commands = False
        self.housekeeping = Housekeeping(self._emit, self.clock.now, self.keepalive_s)  # M113, M155, M31, M500-M503
        self.settings = Settings(self.profile)  # M92, M201, M203-M206, M301: what M503 reports
        self.extruder = Extruder()  # E, which Marlin tracks although the probe rig has no extruder
        for line in banner_lines(self.profile, settings_report(self.settings, comments=True)):
            self._emit(line)

    def reset(self) -> None:
        """Power cycle / reset button: the queue and counters are lost, the probe is unhomed."""
        self.resets += 1
        self.timeline.teleport(self.clock.now(), self.timeline.position_mm(self.clock.now()))
        self._boot()

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

    def _kill(self) -> None:
        self.queue.clear()
        self.rx.clear()
        self.halted = True
        now = self.clock.now()
        self.timeline.teleport(now, self.timeline.position_mm(now))  # steppers stop where they are
        self._emit("echo:M112 Shutdown")
        self._emit(f"Error:{R.ERR_KILLED}")

    # ---- execution ------------------------------------------------------------------------

    def step(self) -> float | None:
        """Run queued commands; real seconds until the head command can go on, or None when idle."""
        housekeeping = self.housekeeping
        if housekeeping.report_every_s and housekeeping.next_report_s <= self.clock.now():  # M155 on: rarely
            housekeeping.reports_due(self.clock.now())
        while self.queue and not self.dead and not self.halted:
            wait = self._run_head()
            if self.halted:  # it ran M112: the queue is gone
                return None
            if wait > 0:
                return min(wait, self.keepalive_s / getattr(self.clock, "speed", 1.0))
            self.queue.popleft()
            self._head_ready = None
            self._after_command()
            if self.rx:
                self._read_lines()
        return None

    def idle(self, real_s: float) -> None:
        """Real seconds passed with the queue empty: with M155 on, the virtual clock follows them, so the reports go on
        as a real board's do (standing still, it left OctoPrint without them); with M155 off it stays put."""
        if self._virtual and real_s > 0 and self.housekeeping.report_every_s and not (self.queue or self.halted):
            self.clock.wait_until(self.clock.now() + real_s)

    def _after_command(self) -> None:
        count = self.executed_count
        if self.faults.reset_after is not None and count == self.faults.reset_after and self.resets == 0:
            self.reset()
        if self.faults.dead_after is not None and count >= self.faults.dead_after and not self.dead:
            self.dead = True
            self.closed = self.faults.dead_closes

    def _wait(self, ready_s: float) -> float:
        """0 when the clock has reached ready_s (virtual time jumps there), else the real seconds left."""
        now = self.clock.now()
        if self._virtual:
            if ready_s > now:
                self.housekeeping.reports_due(ready_s)
                every_s = self.housekeeping.keepalive_s
                for _ in range(min(int((ready_s - now) // every_s), 3) if every_s > 0 else 0):
                    self._emit(f"echo:{R.BUSY_PROCESSING}")
                self.clock.wait_until(ready_s)
            return 0.0
        left = self.clock.wait_until(ready_s)
        every_s = self.housekeeping.keepalive_s
        if left > 0 and every_s > 0 and now - self._last_busy >= every_s:
            self._last_busy = now
            self._emit(f"echo:{R.BUSY_PROCESSING}")
        return left

    def _run_head(self) -> float:
        number, text, code, line, raw = self.queue[0]
        if self._head_ready is None:  # first visit: start the command, decide when it may finish
            if self.echo_commands:
                self._emit(f"echo:{raw}", eol=b"\r\n")
            if code == "M112":  # numbered, it reached the queue: it kills as it runs
                self.executed.append((number, text))
                self.executed_count += 1
                self._kill()
                return 0.0
            self._last_busy = self.clock.now()
            ready = self._start(code, line)
            self._head_ready = self.clock.now() if ready is None else ready
        wait = self._wait(self._head_ready)
        if wait > 0:
            return wait
        moved = code in _MOVES and line is not None and not self._refuses_motion()
        if moved:
            self._move(line)  # type: ignore[arg-type]
        self.executed.append((number, text))
        self.executed_count += 1
        if self.faults.busy_storm and self.rng.random() < self.faults.busy_storm:
            for _ in range(int(self.rng.integers(3, 30))):
                self._emit(f"echo:{R.BUSY_PROCESSING}")
        if moved or not self._reply(code, line, text):
            self._ok(number)
        return 0.0

    @property
    def homed_all(self) -> bool:
        h = self.homed
        return h[0] and h[1] and h[2]

    def _refuses_motion(self) -> bool:
        """NO_MOTION_BEFORE_HOMING: Marlin's G0/G1 does nothing but say so while an axis is not homed."""
        return self.no_motion_before_homing and not self.homed_all

    def _start(self, code: str, line: GcodeLine | None) -> float | None:
        """Side effects at the start of a command; the time its `ok` waits for (None: at once)."""
        now = self.clock.now()
        tl = self.timeline
        if code in _MOVES:
            return None if self._refuses_motion() else tl.slot_free_s(now, self.profile.planner_buffer_size)
        if code == "M400":
            return tl.end_s
        if code == "M410":  # Planner::quick_stop then holds the planner for a second (cleaning_buffer_counter)
            self._quick_stop()
            return now + QUICK_STOP_HOLD_S
        if code == "G4" and line is not None:
            return max(now, tl.end_s) + (line.get("P", 0.0) or 0.0) / 1000.0 + (line.get("S", 0.0) or 0.0)
        if code == "G28":
            return self._home(*homing_request(line.params if line is not None else {}))
        return None

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
        if self.queue and self._head_ready is not None and (self.queue[0][2] in _MOVES or self.queue[0][2] == "M400"):
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

    def _reply(self, code: str, line: GcodeLine | None, text: str) -> bool:
        """Replies of a command other than a move that ran; True when its `ok` is already sent."""
        if code in _MOVES:
            if self._refuses_motion():  # motion.cpp homing_needed_error: every main axis not homed, named
                self._emit("echo:Home " + "".join(a for a, h in zip("XYZ", self.homed) if not h) + " First")
        elif code in _MODES or code == "G92":
            if line is not None:
                self.machine.step(line)
                self._round_belief()
            self.extruder.mode(code)
            if code == "G92":
                e = line.get("E") if line is not None else None
                if isinstance(e, float):
                    self.extruder.set_position(e)
                self._emit(self._m114())  # G92 reports the position it set
        elif code == "M110":  # M110.cpp: N sets the line number; alone, it reports it
            n = line.get("N") if line is not None else None
            if isinstance(n, float):
                self.last_n = int(n)
            else:
                self._emit(f"Line: {self.last_n}")
        elif code in SETTINGS:
            if self.settings.run(code, line, self._emit) and code == "M206":
                self._emit(self._m114())  # M206.cpp reports the position (the offset applies at the next G28)
        elif code == "M114" or code == "G28":  # G28 reports where it left the head (report_current_position)
            self._emit(self._m114())
        elif code == "M119":
            self._emit("Reporting endstop status")
            here = self.timeline.position_mm(self.clock.now())
            for i, axis in enumerate("xyz"):
                hit = self.homed[i] and here[i] <= tuple(self.profile.soft_min_mm)[i] + 1e-9
                self._emit(f"{axis}_min: {'TRIGGERED' if hit else 'open'}")
        elif code == "M211" and line is not None:
            if "S" in line.params:  # sets, silently: parser.value_bool (a bare S is on, S0 off)
                s = line.params["S"]
                self._set_soft_endstops(not isinstance(s, float) or int(s) > 0)
            else:
                self._m211_report()
        elif code == "M118" and line is not None:
            prefix = "echo:" if line.get("E") else ("//" if line.get("A") else "")
            self._emit(prefix + line.text, eol=b"\r\n")
        elif code == "M111":
            self.echo_commands = bool(line is not None and int(line.get("S", 0) or 0) & 1)
            self._emit("echo:DEBUG:ECHO" if self.echo_commands else "echo:DEBUG:off")
        elif code == "M105":
            self._emit("ok " + TEMPERATURES, is_ok=True)
            return True
        elif code == "M115":
            for text_line in m115_lines():
                self._emit(text_line)
        elif code in HOUSEKEEPING:
            if code in ("M501", "M502"):  # no EEPROM: both load the configuration's defaults
                self.settings.load_defaults()
            self.housekeeping.run(code, line, lambda comments: settings_report(self.settings, comments))
        elif code not in _QUIET and code not in _SILENT and code[:1] != "T":  # a tool change: ok (one tool)
            self._emit(f'echo:{R.UNKNOWN_COMMAND}{text}"')
        return False

    def _ok(self, number: int | None) -> None:
        if not self.advanced_ok:
            if self._plain_ok and not self.dead:
                self.out += _OK
            else:
                self._emit(R.OK, is_ok=True)
            return
        # Marlin's planner keeps one slot empty: an idle planner of 16 reports P15
        free = self.profile.planner_buffer_size - 1 - self.timeline.pending(self.clock.now())
        tag = f" N{number}" if number is not None else ""
        self._emit(f"ok{tag} P{free} B{self.bufsize - len(self.queue)}", is_ok=True)

    def _m114(self) -> str:
        m = self.machine
        return position_report(m.position_mm, m.offset_mm, self.extruder.e_mm, self.settings.steps_per_mm)

    def _m211_report(self) -> None:
        """M211 alone (M211.cpp M211_report): the state, then the limits in logical mm (G92 shifts them)."""
        on = self.soft_endstops
        self._emit(f"  M211 S{int(on)} ; {'ON' if on else 'OFF'}")
        o = self.machine.offset_mm
        lo = [v + k + 0.0 for v, k in zip(self.profile.soft_min_mm, o)]
        hi = [v + k + 0.0 for v, k in zip(self.profile.soft_max_mm, o)]
        m = marlin_float
        self._emit(f"  Min:  X{m(lo[0])} Y{m(lo[1])} Z{m(lo[2])}   Max:  X{m(hi[0])} Y{m(hi[1])} Z{m(hi[2])}")

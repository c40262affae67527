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
planner delays the `ok`). What the firmware believes of its axes and how the probe moves (homing,
moves before homing from the believed zeros, the soft endstops) is sim.belief's, the base class;
`no_motion_before_homing=True` refuses a move before homing instead (`echo:Home XYZ First`, then `ok`), as a Marlin
built with that option. Time is a clock object (sim.clock): virtual (jumps to when the motion is
done; no sleeping) or scaled real time. Faults (faults.FaultConfig) are drawn from a seeded numpy
Generator. Its memory is bounded however long it runs: the latest `history_lines` executed commands
(and `executed_count` of them all) and the latest `keep_segments` moves (sim.motion.Timeline).
"""

from __future__ import annotations

import collections

import numpy as np

from neatskin.gcode.machine import Machine, MaybeXyz, homing_request
from neatskin.gcode.parse import GcodeLine
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import replies as R
from neatskin.sim.belief import MOVES, Belief
from neatskin.sim.clock import ScaledClock, VirtualClock
from neatskin.sim.extruder import Extruder, position_report
from neatskin.sim.faults import FaultConfig
from neatskin.sim.firmware_texts import banner_lines, m115_lines
from neatskin.sim.housekeeping import CODES as HOUSEKEEPING
from neatskin.sim.housekeeping import TEMPERATURES, Housekeeping
from neatskin.sim.motion import Timeline
from neatskin.sim.settings import CODES as SETTINGS
from neatskin.sim.settings import Settings, marlin_float, settings_report

__all__ = ["MarlinCore", "ScaledClock", "VirtualClock"]

_MODES = frozenset({"G90", "G91", "M82", "M83"})
_SILENT = frozenset({"G0", "G1", "G4", "M400", "M111"})
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


class MarlinCore(Belief):
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
        moved = code in MOVES and line is not None and not self._refuses_motion()
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

    def _start(self, code: str, line: GcodeLine | None) -> float | None:
        """Side effects at the start of a command; the time its `ok` waits for (None: at once)."""
        now = self.clock.now()
        tl = self.timeline
        if code in MOVES:
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

    def _reply(self, code: str, line: GcodeLine | None, text: str) -> bool:
        """Replies of a command other than a move that ran; True when its `ok` is already sent."""
        if code in MOVES:
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
        elif code == "M999":  # M999.cpp: running again; unless S is true, queue.cpp's flush_and_request_resend
            s = line.params.get("S", 0.0) if line is not None else 0.0  # parser.boolval('S'): a bare S is true
            if isinstance(s, float) and int(s) <= 0:
                self._request_resend()
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

"""The simulated printer's firmware: Marlin's serial queue, command set and replies, without any I/O.

`MarlinCore.receive(bytes)` takes what the host wrote; `step()` runs what can run now and says
how long (in real seconds) until something is due; `take_output()` gives the reply bytes.
Line numbers, checksums and resends follow Marlin 2.1's queue.cpp (a repeated line just below
the counter is dropped silently; `marlin_version="2.0"` answers it with an error instead; a bare
`ok` follows every `Resend:`, as Marlin sends it; `ok_after_resend=False` leaves it out, as a
Repetier-like peer). What it prints matches the real firmware byte for byte where
tests/test_marlin_real_vs_sim.py compares them (`\r\n` after M118 and the M111 echo, the
banner, M115's capabilities, M114 zeros before homing, `Count` at the end of the queued motion,
M112 only as a command, nothing after a kill until a reset, moves before homing). Commands run
in order from a BUFSIZE-slot queue; moves go to a planner of `planner_buffer_size` slots (a full
planner delays the `ok`). As stock Marlin (built without NO_MOTION_BEFORE_HOMING), a move before
homing runs from where the firmware believes the head is (zeros at boot), unclamped on the axes not
homed, and the probe moves by the same steps from where it really is (`_frame_mm`: real minus
believed, per axis; zero once the axis is homed); `no_motion_before_homing=True` refuses it instead
(`echo:Home XYZ First`, then `ok`), as a Marlin built with that option. Time is a clock object:
virtual (jumps to when the motion is done; no sleeping) or scaled real time. Faults
(faults.FaultConfig) are drawn from a seeded numpy Generator.
Its memory is bounded however long it runs: the latest `history_lines` executed commands (and
`executed_count` of them all) and the latest `keep_segments` moves (sim.motion.Timeline).
"""

from __future__ import annotations

import collections
import math
import re
import time

import numpy as np

from neatskin.errors import ConfigError
from neatskin.gcode.machine import Machine, MaybeXyz, Move, Xyz
from neatskin.gcode.parse import GcodeLine, checksum, parse_line
from neatskin.gcode.profile import PrinterProfile
from neatskin.marlin import replies as R
from neatskin.sim.faults import FaultConfig
from neatskin.sim.firmware_texts import STEPS_PER_MM, banner_lines, m115_lines
from neatskin.sim.motion import Timeline

_N = re.compile(r"N\s*(-?\d+)")
_DIGITS = re.compile(r"\d+")
_EOL = re.compile(rb"[\r\n]")
_FRAMED = re.compile(r"N(\d+)([^*]*)\*(\d+)")  # the common framed line: N<n> <command>*<checksum>
_MOVES = frozenset({"G0", "G1"})
_MODES = frozenset({"G90", "G91", "M82", "M83"})
_SILENT = frozenset({"G0", "G1", "G4", "G28", "M400", "M999", "M111"})
_OK = b"ok\n"
_PARSE_CACHE_LINES = 1024  # distinct command texts kept parsed (the repeated ones come first)
# (M84/M18 among them: stock Marlin keeps the axes homed when it turns the steppers off, HOME_AFTER_DEACTIVATE off)
_QUIET = frozenset(
    {"G21", "G90", "G91", "M17", "M18", "M82", "M83", "M84", "M104", "M106", "M107", "M117", "M140", "M220", "M221"}
)


class VirtualClock:
    """Simulated seconds that jump forward to whatever the printer waits for."""

    def __init__(self) -> None:
        self.t_s = 0.0

    def now(self) -> float:
        return self.t_s

    def wait_until(self, t_s: float) -> float:
        self.t_s = max(self.t_s, t_s)
        return 0.0


class ScaledClock:
    """Real time, `speed` times faster (speed=1: wall clock)."""

    def __init__(self, speed: float = 1.0) -> None:
        if speed <= 0:
            raise ConfigError(f"time speed {speed!r} must be > 0", field="speed", fix="use e.g. 1 or 10")
        self.speed = speed
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.speed

    def wait_until(self, t_s: float) -> float:
        return max(0.0, (t_s - self.now()) / self.speed)


class MarlinCore:
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
        self.profile = profile
        self.faults = faults
        self.rng = np.random.default_rng(seed)
        self.clock = clock or VirtualClock()
        self._virtual = isinstance(self.clock, VirtualClock)
        self.advanced_ok = advanced_ok
        self.marlin_version = marlin_version
        self.ok_after_resend = ok_after_resend
        self.no_motion_before_homing = no_motion_before_homing
        self.bufsize = bufsize
        # the serial receive ring: bytes past it are lost, as on an AVR board (None: unbounded, as the
        # native build's HAL, which reads stdin only into free space)
        self.rx_buffer_size = rx_buffer_size
        self.rx_overflow_bytes = 0
        self.echo_commands = False  # M111 S1
        self.keepalive_s = keepalive_s
        self.timeline = Timeline(profile, tuple(profile.park_mm), keep_segments)
        # bounded, so memory stays flat as a campaign grows: the latest lines, and a count of them all
        self.executed: collections.deque[tuple[int | None, str]] = collections.deque(maxlen=history_lines)
        self.executed_count = 0
        self.clip_events: collections.deque[tuple[float, str, MaybeXyz, MaybeXyz]] = collections.deque(
            maxlen=history_lines
        )
        self.out = bytearray()
        self.dead = False
        self.closed = False
        self.resets = 0
        self._parsed: dict[str, tuple[str, GcodeLine | None]] = {}
        self._plain_ok = not (faults.drop_ok or faults.duplicate) and R.OK == "ok"
        self._boot()

    # ---- state ----------------------------------------------------------------------------

    def _boot(self) -> None:
        self.rx = bytearray()
        # (line number, command, code, parsed, the line as received: M111 S1 echoes it)
        self.queue: collections.deque[tuple[int | None, str, str, GcodeLine | None, str]] = collections.deque()
        self.last_n = 0
        self.homed = [False, False, False]
        # the one G-code machine model (gcode.machine): native position, G92 offsets, modes: what the firmware
        # believes (zeros at boot, as Marlin); the timeline is where the probe is, _frame_mm the difference
        self.machine = Machine(
            self.profile,
            start_mm=(0.0, 0.0, 0.0),
            feed_mm_s=self.profile.travel_feed_mm_s,
            homing_time_s=self.profile.homing_time_s,
        )
        self._frame_mm = list(self.timeline.end_mm)
        self._set_soft_endstops(True)
        self.halted = False
        self._head_ready: float | None = None
        self._last_busy = self.clock.now()
        self.echo_commands = False
        for line in banner_lines(self.profile):
            self._emit(line)

    def reset(self) -> None:
        """Power cycle / reset button: the queue and counters are lost, the probe is unhomed."""
        self.resets += 1
        self.timeline.teleport(self.clock.now(), self.timeline.position_mm(self.clock.now()))
        self._boot()

    def take_output(self) -> bytes:
        data = bytes(self.out)
        self.out.clear()
        return data

    def _set_soft_endstops(self, on: bool) -> None:
        """M211: the machine clamps native targets to the bed, and to the soft limits while they are on."""
        self.soft_endstops = on
        self._apply_limits()

    def _travel_mm(self, soft: bool) -> tuple[Xyz, Xyz]:
        """The bed's travel (lo, hi), within the soft limits when `soft`."""
        p = self.profile
        lo = (0.0, 0.0, p.soft_min_mm.z)
        hi = (p.bed_x_mm, p.bed_y_mm, p.soft_max_mm.z)
        if soft:
            lo = (max(lo[0], p.soft_min_mm.x), max(lo[1], p.soft_min_mm.y), max(lo[2], p.soft_min_mm.z))
            hi = (min(hi[0], p.soft_max_mm.x), min(hi[1], p.soft_max_mm.y), min(hi[2], p.soft_max_mm.z))
        return lo, hi

    def _apply_limits(self) -> None:
        # Marlin's apply_motion_limits clamps only the axes it has homed (motion.cpp: `if (axis_was_homed(..))`)
        lo, hi = self._travel_mm(self.soft_endstops)
        h = self.homed
        self.machine.limits_mm = (
            (lo[0] if h[0] else -math.inf, lo[1] if h[1] else -math.inf, lo[2] if h[2] else -math.inf),
            (hi[0] if h[0] else math.inf, hi[1] if h[1] else math.inf, hi[2] if h[2] else math.inf),
        )

    def _emit(self, text: str, *, is_ok: bool = False, eol: bytes = b"\n") -> None:
        if self.dead:
            return
        if is_ok and self.faults.drop_ok and self.rng.random() < self.faults.drop_ok:
            return
        line = text.encode("ascii") + eol
        self.out += line
        if self.faults.duplicate and self.rng.random() < self.faults.duplicate:
            self.out += line

    # ---- serial input ---------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        if self.dead or self.halted:
            return  # a killed Marlin reads nothing until it is reset
        room = None if self.rx_buffer_size is None else self.rx_buffer_size - 1 - len(self.rx)
        if room is not None and len(data) > room:
            self.rx_overflow_bytes += len(data) - max(room, 0)
            data = data[: max(room, 0)]
        self.rx += data
        self._read_lines()

    def _read_lines(self) -> None:
        rx = self.rx
        while len(self.queue) < self.bufsize and not self.dead:
            eol = _EOL.search(rx)
            if eol is None:
                return
            cut = eol.start()
            raw = bytes(rx[:cut])
            del rx[: cut + 1]
            self._accept(raw)

    def _accept(self, raw: bytes) -> None:
        faults = self.faults
        if faults.drop_line and raw.strip() and self.rng.random() < faults.drop_line:
            return
        if faults.corrupt and raw.strip() and self.rng.random() < faults.corrupt:
            raw = self._corrupt(raw)
        text = raw.decode("ascii", "replace").strip()
        if not text or self.halted:
            return
        number = None
        framed = _FRAMED.fullmatch(text)
        if framed is not None and "M110" not in text:  # the common case, checked as the general path below
            number = int(framed.group(1))
            if not self._in_sequence(number):
                return
            if int(framed.group(3)) != checksum(text[: framed.start(3) - 1]):
                self._line_error(R.ERR_CHECKSUM)
                return
            self.last_n = number
            self._enqueue(number, framed.group(2).strip(), text)
            return
        if text.startswith("N"):
            is_m110 = "M110" in text
            npos = text
            if is_m110 and "N" in text[4:]:
                npos = text[text.index("N", 4) :]
            match = _N.match(npos)
            number = int(match.group(1)) if match else 0
            if not is_m110 and not self._in_sequence(number):
                return
            star = text.rfind("*")
            if star < 0:
                self._line_error(R.ERR_NO_CHECKSUM)
                return
            digits = _DIGITS.match(text, star + 1)
            if digits is None or int(digits.group(0)) != checksum(text[:star]):
                self._line_error(R.ERR_CHECKSUM)
                return
            self.last_n = number
            head = _N.match(text)
            self._enqueue(number, text[head.end() : star].strip() if head else text[:star].strip(), text)
            return
        if text.startswith("M112"):  # no emergency parser: queue.cpp kills on an unnumbered M112 as it reads it
            self._kill()
            return
        self._enqueue(number, text, text)

    def _in_sequence(self, number: int) -> bool:
        """True for the next line number; otherwise the line is refused (or dropped) here."""
        if number == self.last_n + 1:
            return True
        if not (self.marlin_version >= "2.1" and self.last_n - 1 <= number <= self.last_n):
            self._line_error(R.ERR_LINE_NO)
        # else: a repeat from a crossed resend, dropped without a word (Marlin 2.1)
        return False

    def _enqueue(self, number: int | None, text: str, raw: str) -> None:
        """Queue a command, parsed once (Marlin parses at execution; the result is the same).

        A campaign repeats most of its lines (`M400`, the descend and lift moves): each distinct
        text is parsed once (a bounded cache of immutable parses)."""
        parsed = self._parsed.get(text)
        if parsed is None:
            try:
                line = parse_line(text)
            except ConfigError:
                line = None
            parsed = (line.code if line is not None else text.split(" ", 1)[0], line)
            if len(self._parsed) < _PARSE_CACHE_LINES:
                self._parsed[text] = parsed
        self.queue.append((number, text, parsed[0], parsed[1], raw))

    def _corrupt(self, raw: bytes) -> bytes:
        # never the leading 'N': a line that loses it is taken unnumbered, a hole in Marlin's protocol
        start = 1 if raw.startswith(b"N") else 0
        if len(raw) <= start:
            return raw
        i = int(self.rng.integers(start, len(raw)))
        choices = [c for c in b"0123456789ABCDEFGXYZ .-" if c != raw[i]]
        return raw[:i] + bytes([choices[int(self.rng.integers(len(choices)))]]) + raw[i + 1 :]

    def _line_error(self, message: str) -> None:
        self._emit(f"Error:{message}{self.last_n}")
        self.rx.clear()  # Marlin empties its RX buffer before asking again
        self._emit(f"{R.RESEND}{self.last_n + 1}")
        if self.ok_after_resend:
            self._emit(R.OK, is_ok=True)  # bare even with ADVANCED_OK (queue.cpp flush_and_request_resend)

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
                for _ in range(min(int((ready_s - now) // self.keepalive_s), 3)):
                    self._emit(f"echo:{R.BUSY_PROCESSING}")
                self.clock.wait_until(ready_s)
            return 0.0
        left = self.clock.wait_until(ready_s)
        if left > 0 and now - self._last_busy >= self.keepalive_s:
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
        if code == "G4" and line is not None:
            return max(now, tl.end_s) + (line.get("P", 0.0) or 0.0) / 1000.0 + (line.get("S", 0.0) or 0.0)
        if code == "G28":
            event = self.machine.home(
                tuple(i for i, a in enumerate("XYZ") if line is not None and a in line.params) or (0, 1, 2)
            )
            for i in event.axes:
                self.homed[i] = True
                self._frame_mm[i] = 0.0
            self._apply_limits()
            # the axes homed go home; the others stay where the probe is
            end = tuple(h if i in event.axes else p for i, (h, p) in enumerate(zip(event.end_mm, tl.end_mm)))
            return tl.add_homing(now, end, event.duration_s).t1_s  # type: ignore[arg-type]
        return None

    def _move(self, line: GcodeLine) -> None:
        event = self.machine.step(line)
        assert isinstance(event, Move) and event.duration_s is not None  # the machine starts at zeros: all known
        now = self.clock.now()
        if event.clamped:
            self.clip_events.append((now, line.raw, event.requested_mm, event.end_mm))
        if self.homed_all:
            self.timeline.add(now, event)
            return
        # not homed: the steppers step from where the probe is; a stop at the end of the bed's travel loses steps
        lo, hi = self._travel_mm(False)
        frame = self._frame_mm
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
            if code == "G92":
                self._emit(self._m114())  # G92 reports the position it set
        elif code == "M110" and line is not None:
            self.last_n = int(line.get("N", 0.0) or 0)
        elif code == "M114":
            self._emit(self._m114())
        elif code == "M119":
            self._emit("Reporting endstop status")
            here = self.timeline.position_mm(self.clock.now())
            for i, axis in enumerate("xyz"):
                hit = self.homed[i] and here[i] <= tuple(self.profile.soft_min_mm)[i] + 1e-9
                self._emit(f"{axis}_min: {'TRIGGERED' if hit else 'open'}")
        elif code == "M211":
            if line is not None and line.get("S") is not None:
                self._set_soft_endstops(bool(line.get("S")))
            self._emit(self._m211())
        elif code == "M118" and line is not None:
            prefix = "echo:" if line.get("E") else ("//" if line.get("A") else "")
            self._emit(prefix + line.text, eol=b"\r\n")
        elif code == "M111":
            self.echo_commands = bool(line is not None and int(line.get("S", 0) or 0) & 1)
            self._emit("echo:DEBUG:ECHO" if self.echo_commands else "echo:DEBUG:off")
        elif code == "M105":
            self._emit("ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0", is_ok=True)
            return True
        elif code == "M115":
            for text_line in m115_lines():
                self._emit(text_line)
        elif code not in _QUIET and code not in _SILENT:
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
        # the planner's position (the end of the queued motion) as Marlin reports it, zeros before homing
        native = [p if p is not None else 0.0 for p in self.machine.position_mm]
        logical = [p + o for p, o in zip(native, self.machine.offset_mm)]
        counts = [round(a * s) for a, s in zip(native, STEPS_PER_MM)]
        return (
            f"X:{logical[0]:.2f} Y:{logical[1]:.2f} Z:{logical[2]:.2f} E:0.00 "
            f"Count X:{counts[0]} Y:{counts[1]} Z:{counts[2]}"
        )

    def _m211(self) -> str:
        lo, hi = self.profile.soft_min_mm, self.profile.soft_max_mm
        return (
            f"echo:Soft endstops: {'ON' if self.soft_endstops else 'OFF'}  "
            f"Min:  X{lo.x:.2f} Y{lo.y:.2f} Z{lo.z:.2f}   Max:  X{hi.x:.2f} Y{hi.y:.2f} Z{hi.z:.2f}"
        )

"""One command script replayed line by line against any Marlin on a pty: the real firmware or the simulator.

Each entry is written as is (framed lines carry their own N and checksum, so a bad checksum or a
skipped number is part of the script); the replies are read until the `ok` that answers it (both of M999's), or, for a
line answered by no `ok` (a kill, a line ignored while halted), until its quiet time passes.
"""

from __future__ import annotations

import math
import os
import select
import time

from neatskin.marlin.replies import frame


def bad(line: bytes) -> bytes:
    """The line with its checksum changed."""
    head, cs = line.rstrip(b"\n").rsplit(b"*", 1)
    return head + b"*" + str((int(cs) + 1) % 256).encode() + b"\n"


# (bytes written, the quiet time in s after which the answer is taken to be complete). A line answered with an
# `ok` (OK_WAIT_S) is read until that `ok`, however long its answer pauses: no quiet time can cut it. A fixed one
# did, on a loaded machine: G28's keep-alives come 2 s apart on the firmware, and a firmware (or relay thread) held
# off the CPU for a second past the 3 s then allowed cut the answer there and shifted every later one by a line.
# The replay's max_wait_s still bounds every line: an `ok` that never comes ends the read there, and the
# comparison of the two transcripts fails on it. A line answered by no `ok` ends its read at its quiet time.
OK_WAIT_S = math.inf
SCRIPT: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (frame("M115", 1), OK_WAIT_S),
    (frame("M114", 2), OK_WAIT_S),
    (frame("M118 E1 hi", 3), OK_WAIT_S),
    (frame("M118 A1 hi", 4), OK_WAIT_S),
    (frame("M118 hi", 5), OK_WAIT_S),
    (frame("M118 E1 M112 in text", 6), OK_WAIT_S),
    (frame("G4 P10", 7), OK_WAIT_S),
    (frame("M400", 8), OK_WAIT_S),
    (frame("M111 S1", 9), OK_WAIT_S),
    (frame("M118 E1 x", 10), OK_WAIT_S),
    (bad(frame("G92 X10 Y10 Z10", 11)), OK_WAIT_S),
    (frame("M118 E1 skipped", 12), OK_WAIT_S),
    (frame("G92 X10 Y10 Z10", 11), OK_WAIT_S),
    (frame("M114", 12), OK_WAIT_S),
    (frame("M400", 13), OK_WAIT_S),
    (frame("G999", 14), OK_WAIT_S),
    (frame("M111 S0", 15), OK_WAIT_S),
    (frame("M118 E1 y", 16), OK_WAIT_S),
    (frame("M112", 17), 1.0),
    (frame("M999", 18), 0.5),
    (b"M999\n", 0.5),
    (b"M110 N0\n", 0.5),
]

# M999 on a running printer (M999.cpp): without a true S it calls queue.cpp's flush_and_request_resend, which empties
# the receive buffer and prints `Resend: <last N + 1>` and a bare `ok` (ADVANCED_OK or not), before the command's own
# `ok` (`ok P15 B3` with ADVANCED_OK; `ok N11 P15 B3` for a numbered M999); `M999 S1` (S alone too) only its ok,
# `S0` asks again. The line after it is the one asked for. (M999 after a kill is in SCRIPT: nothing answers.)
M999_SCRIPT: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    *((frame("M400" if n % 2 else "M114", n), OK_WAIT_S) for n in range(1, 10)),
    (b"M999\n", OK_WAIT_S),
    (frame("M114", 10), OK_WAIT_S),
    (b"M999 S1\n", OK_WAIT_S),
    (b"M999 S\n", OK_WAIT_S),
    (b"M999 S0\n", OK_WAIT_S),
    (frame("M999", 11), OK_WAIT_S),
    (frame("M400", 12), OK_WAIT_S),
    (b"M110 N0\n", OK_WAIT_S),
    (b"M999\n", OK_WAIT_S),
]

# Motion before homing: stock Marlin (no NO_MOTION_BEFORE_HOMING) moves from where it believes it is (zeros at
# boot), with no word, and clamps only the axes it has homed (none yet: below the soft minimum is taken). Short
# moves: the firmware runs them in real time. M114 reports the end of the queued motion, so it is exact at once.
BEFORE_HOMING: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (frame("M114", 1), OK_WAIT_S),
    (frame("G1 X10 F3000", 2), OK_WAIT_S),
    (frame("M114", 3), OK_WAIT_S),
    (frame("G0 Z5", 4), OK_WAIT_S),
    (frame("G1 X-5 Y-2.5", 5), OK_WAIT_S),
    (frame("M400", 6), OK_WAIT_S),
    (frame("M114", 7), OK_WAIT_S),
    (frame("G91", 8), OK_WAIT_S),
    (frame("G1 X1 Y1 Z-1", 9), OK_WAIT_S),
    (frame("G90", 10), OK_WAIT_S),
    (frame("M400", 11), OK_WAIT_S),
    (frame("M114", 12), OK_WAIT_S),
    (frame("M119", 13), OK_WAIT_S),
    (frame("G92 X0 Y0", 14), OK_WAIT_S),
    (frame("G1 X3", 15), OK_WAIT_S),
    (frame("M400", 16), OK_WAIT_S),
    (frame("M114", 17), OK_WAIT_S),
]


def _command(line: bytes) -> bytes:
    """The command word of a script line (`N17 M112*23` -> `M112`), or b"" for none."""
    words = line.split(b";")[0].split(b"*")[0].split()
    if words and words[0].startswith(b"N"):
        words = words[1:]
    return words[0].upper() if words else b""


# Marlin's last words after M112, on the firmware and the simulator alike: the read of an M112 waits for them (up to
# max_wait_s) before its quiet time starts, so a loaded machine that delays them cannot push them into the next
# line's read. No other line answered by no `ok` has an answer to wait for (a comment, M999 while halted).
HALTED = b"kill() called!"


def oks_answering(line: bytes) -> int:
    """How many `ok` lines answer a script line: two for M999 without a true S (the resend request's bare one, then
    its own), one for any other."""
    words = line.split(b";")[0].split(b"*")[0].split()
    if _command(line) != b"M999":
        return 1
    s = [w[1:] for w in words if w.upper().startswith(b"S")]
    return 1 if s and (s[0] == b"" or int(float(s[0])) > 0) else 2


def replay(fd: int, script: list[tuple[bytes, float]] = SCRIPT, max_wait_s: float = 10.0) -> list[tuple[bytes, bytes]]:
    """(line written, every byte read until its `ok`, or until its quiet time passes after an M112's last words or
    any other answer) for each entry of the script, each line's read bounded by max_wait_s."""
    out = []
    for line, quiet_s in script:
        os.write(fd, line)
        got = b""
        end = time.monotonic() + max_wait_s
        halts = _command(line) == b"M112"
        oks = oks_answering(line)
        while (left_s := end - time.monotonic()) > 0:
            wait_s = left_s if halts and HALTED not in got else min(quiet_s, left_s)
            ready, _, _ = select.select([fd], [], [], wait_s)
            if not ready:
                break
            got += os.read(fd, 4096)
            if got.endswith(b"\n") and sum(r.startswith(b"ok") for r in got.splitlines()) >= oks:
                break
        out.append((line, got))
    return out


# Homing and the soft endstops. G28 raises Z before homing X or Y (by Z_CLEARANCE_FOR_HOMING, 5 mm in the stock
# configuration: relative while Z is not homed, to 5 once it is, never down), moves Z to 5 once Z is homed, and
# reports the position; M211 with S only sets (no reply), bare M211 reports; M211 S0 clamps nothing. G28 runs in
# real time on the native board (about 20 s for X from where G0 Z5 leaves it, 40 s for all, a few s for Y once
# homed), so this script homes four times only; `HOMING_WAIT_S` bounds each line's answer.
HOMING_WAIT_S = 120.0
HOMING: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (frame("M211", 1), OK_WAIT_S),
    (frame("M211 S0", 2), OK_WAIT_S),
    (frame("M211", 3), OK_WAIT_S),
    (frame("M211 S", 4), OK_WAIT_S),
    (frame("G0 Z5 F600", 5), OK_WAIT_S),
    (frame("M400", 6), OK_WAIT_S),
    (frame("G28 X", 7), OK_WAIT_S),
    (frame("M114", 8), OK_WAIT_S),
    (frame("G92 Z7", 9), OK_WAIT_S),
    (frame("M211", 10), OK_WAIT_S),
    (frame("G28", 11), OK_WAIT_S),
    (frame("M114", 12), OK_WAIT_S),
    (frame("M211", 13), OK_WAIT_S),
    (frame("G1 X-5 Z-1 F600", 14), OK_WAIT_S),
    (frame("M400", 15), OK_WAIT_S),
    (frame("M114", 16), OK_WAIT_S),
    (frame("M211 S0", 17), OK_WAIT_S),
    (frame("G1 X-5 Z-1", 18), OK_WAIT_S),
    (frame("M400", 19), OK_WAIT_S),
    (frame("M114", 20), OK_WAIT_S),
    (frame("M211 S1", 21), OK_WAIT_S),
    (frame("G1 X-6 Z-2", 22), OK_WAIT_S),
    (frame("M400", 23), OK_WAIT_S),
    (frame("M114", 24), OK_WAIT_S),
    (frame("G1 Z2", 25), OK_WAIT_S),
    (frame("M400", 26), OK_WAIT_S),
    (frame("G28 Y", 27), OK_WAIT_S),
    (frame("G1 Z20", 28), OK_WAIT_S),
    (frame("G28 Y", 29), OK_WAIT_S),
    (frame("M114", 30), OK_WAIT_S),
]

# G28's R word (G28.cpp's seenR): the raise instead of the clearance, relative to where Z is even once Z is homed,
# before Z's own homing too; R0 raises nothing. From a homed Z at 20.
HOMING_R: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (frame("G28", 1), OK_WAIT_S),
    (frame("G1 Z20 F600", 2), OK_WAIT_S),
    (frame("M400", 3), OK_WAIT_S),
    (frame("G28 X R3", 4), OK_WAIT_S),
    (frame("M114", 5), OK_WAIT_S),
    (frame("G28 Y R0", 6), OK_WAIT_S),
    (frame("M114", 7), OK_WAIT_S),
    (frame("G28 Z R2", 8), OK_WAIT_S),
    (frame("M114", 9), OK_WAIT_S),
]


# What a host sends around the motion, and text a host or a hand-typed terminal line can carry: a comment-only
# line (no answer at all), a line of spaces (an unknown command ""), a tab (not skipped as a space is), lower
# case (an unknown command; `y2` no parameter), a comment after a command (its spaces before ';' kept), a line
# past 95 characters (cut there), and commands the stock build runs: M155 (the temperature auto-report M115
# advertises: two reports in 2.5 s), M113 (the keep-alive interval), the print job timer (M75 to M77 and M31:
# none started, 0s), the settings commands (M500 to M503), M108, T0, an arc (G2: its end; M114 reports it), M410.
# The waits end at the `ok`; the comment-only line, answered by nothing, waits its quiet time out. M410 holds the
# planner for a second (Planner::quick_stop's cleaning_buffer_counter), longer on a busy native board: its read
# ends at its `ok` too.
HOST_TEXT: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (b";only a comment\n", 1.0),
    (b"   \n", OK_WAIT_S),
    (b"\tM118 E1 tab\n", OK_WAIT_S),
    (b"g4 p1\n", OK_WAIT_S),
    (b"G92 X1 y2 Z3\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M118 e1 lower flag\n", OK_WAIT_S),
    (b"M118 E1 hi ; a comment\n", OK_WAIT_S),
    (b" M118 E1 leading spaces\n", OK_WAIT_S),
    (b"M118 E1 " + b"c" * 87 + b"\n", OK_WAIT_S),
    (b"M118 E1 " + b"d" * 88 + b"\n", OK_WAIT_S),
    (b"M155 S1\n", OK_WAIT_S),
    (b"G4 P2500\n", OK_WAIT_S),
    (b"M155 S0\n", OK_WAIT_S),
    (b"M113\n", OK_WAIT_S),
    (b"M113 S1\n", OK_WAIT_S),
    (b"M113\n", OK_WAIT_S),
    (b"M31\n", OK_WAIT_S),
    (b"M75\n", OK_WAIT_S),
    (b"M77\n", OK_WAIT_S),
    (b"M500\n", OK_WAIT_S),
    (b"M501\n", OK_WAIT_S),
    (b"M502\n", OK_WAIT_S),
    (b"M503\n", OK_WAIT_S),
    (b"M503 S0\n", OK_WAIT_S),
    (b"M108\n", OK_WAIT_S),
    (b"T0\n", OK_WAIT_S),
    (b"G92 X0 Y0 Z0\n", OK_WAIT_S),
    (b"G2 X2 Y0 I1 J0 F6000\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M410\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
]


# The settings commands a slicer's start code and a host's settings page send (M92, M201, M203-M206, M301, M109/M190
# S0): each sets silently (M206 prints the position; M205 J out of range is refused with an Error:), alone each
# prints its line of the settings report, M503 reports what was set, M502 loads the defaults again. A bare M110
# prints `Line: <the last line number>` (framed too); with N it sets it. M92 X100 makes the step count 100 a mm.
SETTINGS: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (b"M92 X80\n", OK_WAIT_S),
    (b"M201 X3000\n", OK_WAIT_S),
    (b"M203 X300\n", OK_WAIT_S),
    (b"M204 P500\n", OK_WAIT_S),
    (b"M205 J0.02\n", OK_WAIT_S),
    (b"M301 P22\n", OK_WAIT_S),
    (b"M206 X0\n", OK_WAIT_S),
    (b"M109 S0\n", OK_WAIT_S),
    (b"M190 S0\n", OK_WAIT_S),
    (b"M110\n", OK_WAIT_S),
    (frame("M110", 1), OK_WAIT_S),
    (frame("M118 E1 two", 2), OK_WAIT_S),
    (b"M110\n", OK_WAIT_S),
    (b"M110 N7\n", OK_WAIT_S),
    (b"M110\n", OK_WAIT_S),
    (frame("M118 E1 eight", 8), OK_WAIT_S),
    (b"M92\n", OK_WAIT_S),
    (b"M201\n", OK_WAIT_S),
    (b"M203\n", OK_WAIT_S),
    (b"M204\n", OK_WAIT_S),
    (b"M205\n", OK_WAIT_S),
    (b"M206\n", OK_WAIT_S),
    (b"M301\n", OK_WAIT_S),
    (b"G1 X5 F3000\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"M92 X100\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M206 X5 Z-1\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M204 S500\n", OK_WAIT_S),
    (b"M204\n", OK_WAIT_S),
    (b"M204 T1000 R2000\n", OK_WAIT_S),
    (b"M205 J0.5\n", OK_WAIT_S),
    (b"M205 J0.001\n", OK_WAIT_S),
    (b"M205 S1 T2 B3000\n", OK_WAIT_S),
    (b"M301 P22 I1 D100\n", OK_WAIT_S),
    (b"M92 E10\n", OK_WAIT_S),
    (b"M201 X1000 E5000\n", OK_WAIT_S),
    (b"M503 S0\n", OK_WAIT_S),
    (b"M503\n", OK_WAIT_S),
    (b"M502\n", OK_WAIT_S),
    (b"M503 S0\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
]

# M114's numbers as the firmware prints them: 32-bit floats and Marlin's printFloat (add half a hundredth, cut),
# steps by lroundf, at positions on either side of a rounding boundary (52.345 is 52.3450012 as a float: 52.35;
# 2.675 is 2.6749999: 2.67; 0.00625 mm is half a step: 1 step), negative ones (not homed: unclamped) and through
# a G92 offset. The extruder: G1 with E on a cold hot end says `echo: cold extrusion prevented` (the E position
# still moves, and M114 reports it), in absolute and relative E (M82/M83, and G90/G91, which M82/M83 override
# until the next G90/G91). G92 reports the stepper counts, which lag a move in flight: an M400 comes first.
# SETTLE: each M400 of ROUNDING_AND_EXTRUSION is followed by a 0.5 s dwell before a line that reports the stepper
# counts (G92's and M114's "Count"): on a loaded machine the native build once answered G92 with X and Z counts 2 steps
# short of the move's end (X:3 Z:3 against 1 and 1: its stepper thread still finishing the deceleration tail after
# M400's ok), where the simulator, which has no such thread, reports the end. The dwell compares settled counts.
ROUNDING_AND_EXTRUSION: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (b"G1 X52.345 F6000\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X0.125\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X10.015 Y2.675 Z1.005\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X0.00625 Y0.0125 Z0.00125\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"G4 P500\n", OK_WAIT_S),  # see SETTLE below
    (b"G92 X0.5 Y-0.005 Z3.14159\n", OK_WAIT_S),
    (b"G1 X-0.125 Y-0.135 Z-0.335 F600\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X5 E1 F600\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 E1\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"G4 P500\n", OK_WAIT_S),  # see SETTLE below
    (b"G92 E0\n", OK_WAIT_S),
    (b"M83\n", OK_WAIT_S),
    (b"G1 E0.5\n", OK_WAIT_S),
    (b"G1 E0.001\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G91\n", OK_WAIT_S),
    (b"G1 E1\n", OK_WAIT_S),
    (b"G90\n", OK_WAIT_S),
    (b"G1 E2\n", OK_WAIT_S),
    (b"G91\n", OK_WAIT_S),
    (b"M82\n", OK_WAIT_S),
    (b"G1 E1\n", OK_WAIT_S),
    (b"M83\n", OK_WAIT_S),
    (b"G90\n", OK_WAIT_S),
    (b"G1 E1\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X1 E-1\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"G4 P500\n", OK_WAIT_S),  # see SETTLE below
    (b"M114\n", OK_WAIT_S),
]

# M206's home offset applies at the next G28 (set_axis_is_at_home: the axis is believed at its home plus the
# offset): X at the endstop reports -2, Z homes to -1 and then moves to the post-homing 5 (native); a move to 0 is 2
# mm off X's endstop (open) and 1 mm above Z's. Two G28s: about 45 s on the native board.
HOMING_OFFSET: list[tuple[bytes, float]] = [
    (b"M110 N0\n", OK_WAIT_S),
    (b"M206 X-2 Z-1\n", OK_WAIT_S),
    (b"G28\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"G1 X0 Z0 F3000\n", OK_WAIT_S),
    (b"M400\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
    (b"M119\n", OK_WAIT_S),
    (b"M211\n", OK_WAIT_S),
    (b"G28 X\n", OK_WAIT_S),
    (b"M114\n", OK_WAIT_S),
]

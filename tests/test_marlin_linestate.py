"""The sans-IO line protocol, driven deterministically: no pty, no thread, no sleep, a clock that is a number.

Each test feeds LineProtocol exact bytes and times and checks the exact bytes it writes, or couples
it to a DialectFirmware (neatskin.sim.scripted) and checks what the firmware executed.
"""

from __future__ import annotations

import functools
from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from linestate_outcomes import done, error, ok, replies

from neatskin.marlin import errors as E
from neatskin.marlin.jobs import DriverConfig, Job
from neatskin.marlin.linestate import LineProtocol
from neatskin.sim.scripted import DialectFirmware

CONFIG = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, busy_extension_s=0.6, poll_s=0.01)


def cs(n: int, command: str) -> bytes:
    body = f"N{n} {command}".encode()
    return body + b"*" + str(functools.reduce(lambda a, b: a ^ b, body, 0)).encode() + b"\n"


def connected(config: DriverConfig = CONFIG) -> LineProtocol:
    proto = LineProtocol(config)
    hello = proto.start_session(0.0)
    proto.receive(b"start\necho:Marlin 2.1.2.4\n", 0.01)
    assert proto.data_to_send() == []  # the banner settles first
    proto.tick(0.07)
    assert proto.data_to_send() == [b"N0 M110 N0*125\n"]
    proto.receive(b"ok\n", 0.08)
    assert ok(proto, hello) and proto.session
    return proto


def test_exact_lines_for_exact_replies():
    proto = connected()
    g28, move = Job("G28"), Job("G1 X10 Y20 F3000")
    proto.submit([g28, move], 1.0)
    assert proto.data_to_send() == [b"N1 G28*18\n"]  # one line in flight
    proto.receive(b"echo:busy: processing\n", 1.5)
    assert proto.data_to_send() == [] and not done(proto, g28)
    proto.receive(b"ok\n", 2.0)
    assert done(proto, g28) and replies(proto, g28) == []
    assert proto.data_to_send() == [b"N2 G1 X10 Y20 F3000*77\n"]
    proto.receive(b"o", 2.1)  # a reply split across reads waits for its end of line
    assert not done(proto, move)
    proto.receive(b"k\n", 2.2)
    assert done(proto, move) and proto.last_acked == (2, "G1 X10 Y20 F3000")


def test_data_on_the_ok_line_is_kept():
    proto = connected()
    job = Job("M105")
    proto.submit([job], 1.0)
    proto.data_to_send()
    proto.receive(b"ok T:25.00 /0.00 B:24.00 /0.00\n", 1.1)
    assert replies(proto, job) == ["T:25.00 /0.00 B:24.00 /0.00"]


def test_marlin2_replays_after_the_grace_and_learns_no_ok_follows():
    proto = connected()
    jobs = [Job(f"G1 X{i}") for i in range(1, 5)]
    proto.submit(jobs, 1.0)
    t = 1.0
    for n in range(1, 4):  # three resends without an ok: the dialect is learned
        assert proto.data_to_send() == [cs(n, f"G1 X{n}")]
        proto.receive(f"Error:checksum mismatch, Last Line: {n - 1}\nResend: {n}\n".encode(), t)
        proto.tick(t + 0.019)
        assert proto.data_to_send() == []  # waiting 20 ms for an ok that Marlin 2 does not send
        proto.tick(t + 0.021)
        assert proto.data_to_send() == [cs(n, f"G1 X{n}")]
        proto.receive(b"ok\n", t + 0.03)
        t += 0.1
    assert proto.data_to_send() == [cs(4, "G1 X4")]
    proto.receive(b"Error:checksum mismatch, Last Line: 3\nResend: 4\n", t)
    assert proto.data_to_send() == [cs(4, "G1 X4")]  # learned: replayed at once
    proto.receive(b"ok\n", t + 0.01)
    assert all(ok(proto, job) for job in jobs)
    assert proto.stats["lines_resent"] == 4


def test_ok_after_resend_in_a_separate_read_acknowledges_nothing():
    proto = connected()
    job, nxt = Job("G1 X5"), Job("M400")
    proto.submit([job, nxt], 1.0)
    proto.data_to_send()
    proto.receive(b"Error:checksum mismatch, Last Line: 0\nResend: 1\n", 1.0)
    proto.receive(b"ok\n", 1.01)  # Marlin 1.x's ok after Resend, in a read of its own
    assert not done(proto, job)
    assert proto.data_to_send() == [cs(1, "G1 X5")]  # replayed as soon as that ok came
    proto.receive(b"ok\n", 1.05)
    assert done(proto, job) and proto.data_to_send() == [cs(2, "M400")]
    assert proto.stats["oks_swallowed"] == 1


def test_start_flood_at_connect_is_capped():
    config = DriverConfig(boot_timeout_s=0.1, min_timeout_s=0.4, poll_s=0.01, connect_attempts=4)
    proto = LineProtocol(config)
    hello = proto.start_session(0.0)
    sent: list[bytes] = []
    t = 0.0
    for _ in range(10_000):
        proto.tick(t)
        out = proto.data_to_send()
        sent += out
        proto.receive(b"start\n" * len(out) or b"start\n", t)  # a boot loop answers everything with `start`
        if done(proto, hello):
            break
        t += 0.01
    assert isinstance(error(proto, hello), E.ConnectFailed)
    assert "start" in str(error(proto, hello))
    assert len(sent) <= 4 and t < 1.0


def test_resend_0_for_ever_at_connect_is_capped():
    proto = LineProtocol(DriverConfig(boot_timeout_s=0.05, connect_attempts=5))
    hello = proto.start_session(0.0)
    sent: list[bytes] = []
    t = 0.0
    while not done(proto, hello) and t < 100:
        proto.tick(t)
        out = proto.data_to_send()
        sent += out
        for _ in out:
            proto.receive(b"Resend: 0\n", t)
        t += 0.02
    assert isinstance(error(proto, hello), E.ConnectFailed) and "M110 N0 was sent 5 times" in str(error(proto, hello))
    assert sent == [b"N0 M110 N0*125\n"] * 5


def test_connect_deadline_holds_even_when_each_answer_looks_like_progress():
    config = DriverConfig(boot_timeout_s=0.1, connect_timeout_s=1.0, connect_attempts=1000)
    proto = LineProtocol(config)
    hello = proto.start_session(0.0)
    t = 0.0
    while not done(proto, hello) and t < 100:
        proto.tick(t)
        if proto.data_to_send():
            proto.receive(b"echo:busy: processing\n", t)
        t += 0.05
    assert isinstance(error(proto, hello), (E.ConnectFailed, E.NoAnswer))
    assert t <= 1.2


def converse(proto: LineProtocol, firmware: DialectFirmware, jobs: list[Job], max_steps: int = 20_000) -> float:
    """Couple the protocol to a firmware, one reply line per read (the worst split); time is 1 ms a step.

    Checks at every step that no job is done before the firmware ran its command."""
    wire: deque[bytes] = deque()
    t = 1.0
    proto.submit(jobs, t)
    for _ in range(max_steps):
        for data in proto.data_to_send():
            wire.extend(line + b"\n" for line in firmware.feed(data).split(b"\n")[:-1])
        if wire:
            proto.receive(wire.popleft(), t)
        else:
            proto.tick(t)
        ran = firmware.executed.count
        for job in jobs:
            if ok(proto, job) and not job.barrier:
                assert ran(job.command) >= 1, f"{job.command} reported done before it ran"
        if done(proto, jobs[-1]):
            return t
        t += 0.001
    raise AssertionError("no end")


@pytest.mark.parametrize("dialect", ["marlin1", "marlin2", "repetier"])
@pytest.mark.parametrize("ok_after_resend", [None, "right"])
def test_each_dialect_rejecting_one_line_twice_runs_every_command_once_in_order(dialect, ok_after_resend):
    known = None if ok_after_resend is None else dialect != "marlin2"
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, ok_after_resend=known)
    proto = connected(config)
    firmware = DialectFirmware(dialect, reject={5: 2, 9: 1})
    firmware.executed.append("M110 N0")  # the handshake above
    commands = [f"G1 X{i} Y{2 * i}" for i in range(1, 13)]
    jobs = [Job(c) for c in commands]
    converse(proto, firmware, jobs)
    assert all(error(proto, job) is None for job in jobs)
    assert firmware.executed == ["M110 N0", *commands]
    assert proto.stats["lines_resent"] == 3


def test_repetier_error_text_counts_as_a_communication_error():
    proto = connected()
    job = Job("G1 X1")
    proto.submit([job], 1.0)
    proto.data_to_send()
    # the same line refused twice within a second: both are real, neither a duplicate
    for t in (1.0, 1.1):
        proto.receive(b"Error: Checksum mismatch\nResend:1\nok\n", t)
        assert proto.data_to_send() == [cs(1, "G1 X1")] and not done(proto, job)
    proto.receive(b"ok\n", 1.2)
    assert done(proto, job) and proto.stats["duplicate_resends"] == 0


def test_a_duplicated_ok_in_a_separate_read_cannot_finish_a_confirmed_batch_early():
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, confirm_batches=True)
    proto = connected(config)
    firmware = DialectFirmware("marlin2", mode="double_ok")
    firmware.executed.append("M110 N0")
    commands = [f"G1 X{i}" for i in range(1, 40)]
    jobs = [Job(c) for c in commands] + [Job("", barrier=True)]
    converse(proto, firmware, jobs)
    assert firmware.executed[1:] == commands + ["M118 E1 neatskin-probe 40"]
    assert proto.stats["stray_oks"] > 0


def test_position_from_an_ok_line():
    from neatskin.marlin.replies import parse_m114

    proto = connected()
    job = Job("M114")
    proto.submit([job], 1.0)
    proto.data_to_send()
    proto.receive(b"ok X:1.00 Y:2.00 Z:3.00 E:0.00 Count: A:0 B:0 C:0\n", 1.1)
    position = parse_m114(replies(proto, job))
    assert (position.x_mm, position.y_mm, position.z_mm) == (1.0, 2.0, 3.0)


def test_garbage_without_newlines_is_bounded_and_the_line_times_out():
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, probe_attempts=2)
    proto = connected(config)
    job = Job("M105")
    proto.submit([job], 1.0)
    t, sent = 1.0, 0
    while not done(proto, job) and t < 60:
        sent += len(proto.data_to_send())
        proto.receive(b"\xff\x00garbage" * 100, t)
        t += 0.05
    assert isinstance(error(proto, job), E.NoAnswer)
    assert sent <= 4 and len(proto._rx) <= 4096


@settings(max_examples=60, deadline=None)
@given(
    dialect=st.sampled_from(["marlin1", "marlin2", "repetier"]),
    known=st.booleans(),
    rejects=st.dictionaries(st.integers(1, 20), st.integers(1, 3), max_size=6),
    chunk=st.integers(1, 4),
)
def test_any_refusal_pattern_in_any_dialect_runs_each_command_once(dialect, known, rejects, chunk):
    config = DriverConfig(
        boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, ok_after_resend=(dialect != "marlin2") if known else None
    )
    proto = connected(config)
    firmware = DialectFirmware(dialect, reject=rejects)
    commands = [f"G1 X{i}" for i in range(1, 21)]
    jobs = [Job(c) for c in commands]
    wire: deque[bytes] = deque()
    t = 1.0
    proto.submit(jobs, t)
    for _ in range(20_000):
        for data in proto.data_to_send():
            wire.extend(line + b"\n" for line in firmware.feed(data).split(b"\n")[:-1])
        if wire:  # `chunk` reply lines per read
            proto.receive(b"".join(wire.popleft() for _ in range(min(chunk, len(wire)))), t)
        else:
            proto.tick(t)
        for job in jobs:
            assert not (ok(proto, job)) or job.command in firmware.executed
        if done(proto, jobs[-1]):
            break
        t += 0.001
    assert all(ok(proto, job) for job in jobs)
    assert firmware.executed == commands
    assert proto.stats["lines_resent"] == sum(rejects.values())


def _ok_numbers_by_search(text: str) -> tuple[int | None, int | None, int | None]:
    """The reference for an `ok` line's numbers: the first `N`, `P` and `B` word anywhere on it."""
    import re

    found = (re.search(rf"\b{letter}(\d+)", text) for letter in "NPB")
    return tuple(int(m.group(1)) if m else None for m in found)  # type: ignore[return-value]


@settings(max_examples=300, deadline=None)
@given(
    n=st.integers(0, 10**9),
    p=st.integers(0, 999),
    b=st.integers(0, 999),
    form=st.sampled_from(
        [
            "ok N{n} P{p} B{b}",
            "ok  N{n} P{p} B{b}",
            "ok N{n} P{p}",
            "ok P{p} B{b}",
            "ok N{n}",
            "ok N{n} P{p} B{b} T:25.0",
            "ok B{b} P{p} N{n}",
            "ok:N{n} P{p} B{b}",
            "ok T:{p}.0 /0.0 B@:{b}",
        ]
    ),
)
def test_an_ok_line_gives_the_numbers_of_its_words(n, p, b, form):
    """classify's one-match path for Marlin's own `ok N.. P.. B..` gives what searching each word gives, and
    any other shape of `ok` line still reads its words (or none)."""
    from neatskin.marlin.replies import Kind, classify

    text = form.format(n=n, p=p, b=b)
    reply = classify(text)
    assert reply.kind is Kind.OK and reply.text == text
    expected = _ok_numbers_by_search(text) if (" N" in text or " P" in text) else (None, None, None)
    assert (reply.number, reply.planner_free, reply.buffer_free) == expected


@pytest.mark.parametrize("value", [float("nan"), float("inf"), 0.0, -1.0])
@pytest.mark.parametrize("name", ["boot_timeout_s", "connect_timeout_s", "min_timeout_s", "write_timeout_s"])
def test_a_deadline_that_is_never_reached_is_refused_in_the_config(name, value):
    """One ConfigError naming the setting (the CLI prints it; no traceback), not a session that waits for ever."""
    from neatskin.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"DriverConfig\.{name} is {value!r}; it must be a finite number > 0") as e:
        DriverConfig(**{name: value})
    assert e.value.field == name


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_a_boot_wait_that_never_ends_is_refused_at_the_start(value):
    from neatskin.errors import ConfigError

    with pytest.raises(ConfigError, match="the boot wait is .* s; it must be a finite number of seconds"):
        LineProtocol(CONFIG).start_session(0.0, value)
    assert LineProtocol(CONFIG).start_session(0.0, 0.0).command == "M110 N0"  # no wait: hello at once


def test_an_ok_naming_a_line_never_sent_is_one_out_of_step_error():
    """Marlin's ADVANCED_OK copies N from the line it ran (gcode/queue.cpp, ok_to_send): an `ok N1001` when the
    host sent up to N1 cannot be this session's. Before, it retired every line in flight; now one OutOfStep
    fails the session, naming the reply and the last line sent; nothing more goes out."""
    proto = connected()
    first, second = Job("G1 X1 F6000"), Job("G1 X2 F6000")
    proto.submit([first, second], 1.0)
    assert proto.data_to_send() == [cs(1, "G1 X1 F6000")]
    proto.receive(b"ok N1001 P15 B3\n", 1.1)
    failure = error(proto, first)
    assert isinstance(failure, E.OutOfStep) and proto.failure is failure
    assert (
        "the printer said 'ok N1001 P15 B3', acknowledging line N1001, but the last line sent in this session was N1"
        in str(failure)
    )
    assert isinstance(error(proto, second), E.OutOfStep) and proto.data_to_send() == []
    assert proto.last_acked == (0, "M110 N0")


def test_an_ok_naming_a_line_never_sent_is_out_of_step_with_nothing_in_flight():
    proto = connected()
    proto.receive(b"ok N7 P15 B3\n", 1.0)
    assert isinstance(proto.failure, E.OutOfStep) and "last line sent in this session was N0" in str(proto.failure)


def test_the_oks_of_the_lines_sent_and_the_lines_before_are_legal():
    """The rule never fires on a legal reply: `ok N<n>` for each line sent (n up to the last one, pipelined),
    a late ok of a line already acknowledged (stale), and after a new session (M110 N0 numbers from 0 again)
    `ok N0` though the session before reached N3; the oks of a previous host's lines still queued in the
    firmware arrive before the M110's own and are not taken for it."""
    config = DriverConfig(boot_timeout_s=0.5, min_timeout_s=0.4, poll_s=0.01, max_in_flight=4)
    proto = connected(config)
    jobs = [Job(f"G1 X{i} F6000") for i in range(1, 4)]
    proto.receive(b"ok N0 P15 B3\n", 0.9)  # a duplicate ok of the handshake: stale, and ADVANCED_OK is learnt
    proto.submit(jobs, 1.0)
    sent = proto.data_to_send()
    proto.receive(b"ok N1 P15 B3\n", 1.1)
    sent += proto.data_to_send()
    assert sent == [cs(1, "G1 X1 F6000"), cs(2, "G1 X2 F6000"), cs(3, "G1 X3 F6000")]  # pipelined
    proto.receive(b"ok N3 P15 B3\n", 1.2)  # the last one sent: it and the one before it are done
    assert all(ok(proto, job) for job in jobs) and proto.failure is None
    proto.receive(b"ok N2 P15 B3\n", 1.3)  # late, already acknowledged
    assert proto.failure is None and proto.stats["stray_oks"] == 2  # this one and the handshake's duplicate

    hello = proto.start_session(2.0)  # a new session (reconnect): numbering from 0 again
    proto.receive(b"start\n", 2.01)
    proto.tick(2.1)
    assert proto.data_to_send() == [b"N0 M110 N0*125\n"]
    proto.receive(b"ok N41 P15 B1\nok N42 P15 B2\n", 2.2)  # a previous host's queued lines, run first
    assert not done(proto, hello) and proto.failure is None
    proto.receive(b"ok N0 P15 B3\n", 2.3)
    assert ok(proto, hello) and proto.session
    move = Job("G1 X9 F6000")
    proto.submit([move], 2.4)
    assert proto.data_to_send() == [cs(1, "G1 X9 F6000")]
    proto.receive(b"ok N1 P15 B3\n", 2.5)
    assert ok(proto, move) and proto.failure is None


def test_a_handshake_answered_only_with_other_lines_oks_is_out_of_step():
    proto = LineProtocol(CONFIG)
    hello = proto.start_session(0.0)
    proto.receive(b"start\n", 0.01)
    now = 0.1
    proto.tick(now)
    sends = 0
    while proto.failure is None and now < 30:
        for data in proto.data_to_send():
            n = int(data.split()[0][1:])
            sends += n == 0
            proto.receive(f"ok N{n + 1000} P15 B3\n".encode(), now)
        now += 0.05
        proto.tick(now)
    failure = error(proto, hello)
    assert isinstance(failure, E.OutOfStep), failure
    # the handshake goes out once and is said again probe_attempts times: the message counts every send
    assert sends == CONFIG.probe_attempts + 1
    assert f"'M110 N0' (line N0) was sent {sends} times and every `ok` named another line (the latest N1000)" in str(
        failure
    )


@pytest.mark.parametrize("peer", ["silent", "busy"])
def test_the_connect_help_states_the_handshake_limits_the_protocol_keeps(peer):
    """--connect-timeout-s bounds the wait for `start` only; its help (cligroups.CONNECT_AFTER_BOOT) states what
    follows, and this holds those figures to the protocol on its own clock, with DriverConfig's defaults: a
    silent printer fails 4 x 2 s after the boot wait (NoAnswer), one that only says busy 30 s after it
    (ConnectFailed)."""
    from neatskin import cligroups

    config = DriverConfig()
    assert (cligroups.HANDSHAKE_TRIES, cligroups.HANDSHAKE_TRY_S) == (1 + config.probe_attempts, config.min_timeout_s)
    assert cligroups.HANDSHAKE_BUSY_MAX_S == config.connect_timeout_s
    boot_wait_s, step_s = 5.0, 0.01
    proto = LineProtocol(config)
    hello = proto.start_session(0.0, boot_wait_s)
    now, last_busy = 0.0, 0.0
    while proto.failure is None and now < 100:
        now = round(now + step_s, 2)
        if peer == "busy" and now - last_busy >= 2.0:  # Marlin's keep-alive, every 2 s
            proto.receive(b"echo:busy: processing\n", now)
            last_busy = now
        proto.tick(now)
        proto.data_to_send()
    expected_s = boot_wait_s + (
        cligroups.HANDSHAKE_TRIES * cligroups.HANDSHAKE_TRY_S if peer == "silent" else cligroups.HANDSHAKE_BUSY_MAX_S
    )
    assert isinstance(error(proto, hello), E.NoAnswer if peer == "silent" else E.ConnectFailed)
    assert expected_s <= now <= expected_s + 2 * step_s, now
    if peer == "silent":  # the message counts the sends the help states (4), not the repeats (3)
        assert f"within 2 s, {cligroups.HANDSHAKE_TRIES} times" in str(error(proto, hello))

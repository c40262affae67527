"""How jobs ended, read from a LineProtocol's events (Acknowledged / Failed) for the sans-IO tests.

The protocol hands each event out once (`events()`); these helpers collect them per protocol, so a
test can ask of any job whether it ended, how, and with which replies.
"""

from __future__ import annotations

from weakref import WeakKeyDictionary

from neatskin.marlin.errors import MarlinError
from neatskin.marlin.jobs import Acknowledged, Event, Failed, Job
from neatskin.marlin.linestate import LineProtocol

_SEEN: WeakKeyDictionary[LineProtocol, dict[Job, Event]] = WeakKeyDictionary()


def ended(proto: LineProtocol, job: Job) -> Event | None:
    seen = _SEEN.setdefault(proto, {})
    for event in proto.events():
        assert event.job not in seen, f"{event.job.command!r} ended twice"
        seen[event.job] = event
    return seen.get(job)


def done(proto: LineProtocol, job: Job) -> bool:
    return ended(proto, job) is not None


def ok(proto: LineProtocol, job: Job) -> bool:
    return isinstance(ended(proto, job), Acknowledged)


def error(proto: LineProtocol, job: Job) -> MarlinError | None:
    event = ended(proto, job)
    return event.error if isinstance(event, Failed) else None


def replies(proto: LineProtocol, job: Job) -> list[str]:
    event = ended(proto, job)
    assert isinstance(event, Acknowledged), f"{job.command!r} was not acknowledged: {event}"
    return list(event.replies)

"""Pause, continue and stop at safe points: the request file an operator writes and the checkpoint the runner
calls between presses (Bluesky-style checkpoints; no socket into the campaign process).

CAMPAIGN/control.json        the latest request {"action", "id", "requested_at", "by"} and up to 15 before it
                             under "earlier"; replaced atomically
CAMPAIGN/control_state.json  what the runner is doing: {"state": running|paused|stopped, "reason", "since", ...}

Two requests written in quick succession both reach the runner, in order; it acts on each once (by its id).
A request written before this run started or resumed (the manifest's started_at / resumed_at) is ignored;
one written since is acted on at the first safe point, even if it came before the first press. Between presses the probe is already lifted; a pause lifts it
to the safe height and waits; a stop lifts, parks and leaves a campaign that `neatskin campaign resume` finishes.
After `fsr_miss_limit` presses in a row that the FSR missed (each already retried), the runner pauses by itself
and names the likely causes.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal

from neatskin.datasets.durable import write_bytes_durably
from neatskin.errors import DataError

log = logging.getLogger(__name__)

REQUEST_NAME = "control.json"
STATE_NAME = "control_state.json"
ACTIONS = ("pause", "continue", "stop")
DEFAULT_FSR_MISS_LIMIT = 3
POLL_S = 0.2
KEEP_REQUESTS = 16  # requests kept in control.json, so two in quick succession both reach the runner
MAX_PAUSE_S = 7 * 24 * 3600.0  # a pause longer than a week stops the campaign (it stays resumable)

Action = Literal["pause", "continue", "stop"]


@dataclass(frozen=True)
class ControlRequest:
    action: str
    request_id: str
    requested_at: str
    by: str


def _refuse_a_manifest_that_is_no_file(manifest_path: Path, action: str) -> None:
    """A manifest.json that is there but is a folder (or a device, a socket) is no starting run to wait for."""
    if os.path.lexists(manifest_path) and not manifest_path.is_file():
        kind = "a folder" if manifest_path.is_dir() else "not a regular file"
        raise DataError(
            f"manifest.json is {kind}, not a campaign's manifest: the {action} was not recorded",
            file=str(manifest_path),
            fix="give the folder of a campaign (`neatskin campaign run` writes manifest.json as a file); if this is "
            "one, its manifest.json was replaced: restore it from a backup",
        )


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="microseconds")


def request_control(
    folder: str | Path,
    action: str,
    *,
    by: str = "cli",
    wait_s: float = 0.0,
    sleep: Callable[[float], None] = time.sleep,
) -> ControlRequest:
    """Write `action` (pause, continue or stop) as the campaign's control request, atomically.

    A run that is starting has no manifest.json yet (its folder appears in one rename): the request waits up to
    wait_s for it, so a pause sent as the run starts is kept and acted on before the first press. A campaign
    already complete has nothing to pause: refused."""
    folder = Path(folder)
    if action not in ACTIONS:
        raise DataError(f"unknown control action {action!r}", field="action", fix=f"use one of {', '.join(ACTIONS)}")
    manifest_path = folder / "manifest.json"
    deadline = time.monotonic() + wait_s
    _refuse_a_manifest_that_is_no_file(manifest_path, action)
    while not manifest_path.is_file() and time.monotonic() < deadline:
        _refuse_a_manifest_that_is_no_file(manifest_path, action)
        sleep(min(POLL_S, max(0.0, deadline - time.monotonic())))
    if not manifest_path.is_file():
        waited = f" after waiting {wait_s:g} s" if wait_s > 0 else ""
        raise DataError(
            f"no campaign runs in this folder yet (no manifest.json{waited}): the {action} was not recorded",
            file=str(folder),
            field="manifest.json",
            fix="start the campaign first (neatskin campaign run --out DIR); a request sent once it runs is acted "
            "on before its first press. Or check the folder name",
        )
    try:
        status = json.loads(manifest_path.read_text(encoding="utf-8")).get("status")
    except (OSError, ValueError, AttributeError):
        status = None
    if status == "complete":
        raise DataError(
            f"the campaign is already complete: there is nothing to {action}",
            file=str(manifest_path),
            field="status",
            fix=f"nothing to do; `neatskin dataset info {folder}` shows what it holds",
        )
    request = ControlRequest(action, secrets.token_hex(8), _now_iso(), by)
    earlier = [_as_dict(r) for r in read_requests(folder)][-(KEEP_REQUESTS - 1) :]
    payload = {**_as_dict(request), "earlier": earlier}
    write_bytes_durably(folder / REQUEST_NAME, (json.dumps(payload) + "\n").encode())
    return request


def _as_dict(request: ControlRequest) -> dict[str, str]:
    return {"action": request.action, "id": request.request_id, "requested_at": request.requested_at, "by": request.by}


def _from_dict(data: object) -> ControlRequest | None:
    if not isinstance(data, dict) or data.get("action") not in ACTIONS:
        return None
    return ControlRequest(
        str(data["action"]), str(data.get("id", "")), str(data.get("requested_at", "")), str(data.get("by", ""))
    )


def read_requests(folder: str | Path) -> list[ControlRequest]:
    """The folder's recent requests, oldest first ([] when none was written or the file is unreadable)."""
    try:
        data = json.loads((Path(folder) / REQUEST_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    if not isinstance(data, dict):
        return []
    entries = [*(data.get("earlier") or []), data] if isinstance(data.get("earlier", []), list) else [data]
    return [r for r in map(_from_dict, entries) if r is not None]


def read_request(folder: str | Path) -> ControlRequest | None:
    """The latest request in the folder, or None."""
    requests = read_requests(folder)
    return requests[-1] if requests else None


def read_state(folder: str | Path) -> dict[str, object]:
    """The runner's control state ({} when the campaign never wrote one)."""
    try:
        data = json.loads((Path(folder) / STATE_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _parse_time(text: str) -> datetime:
    try:
        value = datetime.fromisoformat(text)
    except ValueError:
        return datetime.min.replace(tzinfo=UTC)
    return value if value.tzinfo else value.replace(tzinfo=UTC)


def _run_started_at(folder: Path) -> datetime | None:
    """When this run of the campaign began (the manifest's resumed_at, else started_at): requests written
    since then are for this run, even one written before the first press."""
    try:
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    stamp = manifest.get("resumed_at") or manifest.get("started_at") if isinstance(manifest, dict) else None
    return _parse_time(stamp) if isinstance(stamp, str) else None


def fsr_miss_cause(n_misses: int, press_ids: Sequence[int]) -> str:
    """The operator's message for an automatic pause after `n_misses` missed presses in a row."""
    ids = ", ".join(str(i) for i in press_ids)
    return (
        f"{n_misses} presses in a row the FSR did not see (press {ids}), each retried: the skin surface is "
        "likely lower than calibrated (check calibration surface_z_mm and the skin's seating), or the FSR is "
        "unplugged (check its connector and the DAQ channel); fix it, then continue, or stop and resume later"
    )


class Checkpoint:
    """The safe point between presses. `after_press(press_id, flags)` returns True to go on, False to stop.

    `lift()` raises the probe to the safe height (pause); `park()` lifts and parks it (stop). `flush()` makes
    the presses a batching writer holds durable, before any pause or stop, so the monitor and `campaign info`
    show every press pressed. `interrupted()` lets a Ctrl-C end a pause. `rehome()` homes the printer again when
    a pause outlasted the firmware's stepper timeout (Marlin turns idle steppers off after
    DEFAULT_STEPPER_DEACTIVE_TIME, and a carriage nudged while they are off would put every later press in the
    wrong place without a word). The runner calls nothing else; every wait polls the request file with a cap.
    """

    def __init__(
        self,
        folder: str | Path,
        *,
        lift: Callable[[], object],
        park: Callable[[], object],
        flush: Callable[[], object] = lambda: None,
        fsr_miss_limit: int = DEFAULT_FSR_MISS_LIMIT,
        interrupted: Callable[[], bool] = lambda: False,
        poll_s: float = POLL_S,
        max_pause_s: float = MAX_PAUSE_S,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
        rehome: Callable[[], object] | None = None,
        stepper_timeout_s: float = 0.0,
    ) -> None:
        self.folder = Path(folder)
        self._lift, self._park, self._flush, self._interrupted = lift, park, flush, interrupted
        self._rehome, self.stepper_timeout_s = rehome, float(stepper_timeout_s)
        self.fsr_miss_limit = int(fsr_miss_limit)
        self.poll_s, self.max_pause_s = poll_s, max_pause_s
        self._sleep, self._clock = sleep, clock
        since = _run_started_at(self.folder)
        self._handled = {  # requests from before this run started or resumed are not for it
            r.request_id for r in read_requests(self.folder) if since is None or _parse_time(r.requested_at) < since
        }
        self._missed: list[int] = []
        self.pauses = 0
        self._write_state("running", None)

    def _write_state(self, state: str, reason: str | None, **extra: object) -> None:
        payload = {"state": state, "reason": reason, "since": _now_iso(), "pauses": self.pauses, **extra}
        write_bytes_durably(self.folder / STATE_NAME, (json.dumps(payload) + "\n").encode(), fsync=False)

    def _new_requests(self) -> list[ControlRequest]:
        """Requests not acted on yet, oldest first; from now on they count as handled."""
        fresh = [r for r in read_requests(self.folder) if r.request_id not in self._handled]
        self._handled.update(r.request_id for r in fresh)
        return fresh

    def after_press(self, press_id: int, flags: Sequence[str]) -> bool:
        """Called once the press is written (durable, or in a batch that a pause or stop flushes first): True
        to run the next press, False to stop here."""
        self._missed = [*self._missed, press_id] if "fsr_missed" in flags else []
        pause_by: str | None = None
        for request in self._new_requests():  # in order: a pause then a continue cancel out
            if request.action == "stop":
                return self._stop(f"stop requested by {request.by}")
            pause_by = request.by if request.action == "pause" else None
        if self.fsr_miss_limit > 0 and len(self._missed) >= self.fsr_miss_limit:
            reason = fsr_miss_cause(len(self._missed), self._missed)
            log.warning("campaign paused: %s", reason)
            return self._pause(reason, auto=True)
        if pause_by is not None:
            log.warning(
                "campaign paused at press %d by %s; continue with: neatskin campaign continue %s",
                press_id,
                pause_by,
                self.folder,
            )
            return self._pause(f"pause requested by {pause_by}", auto=False)
        return True

    def _stop(self, reason: str) -> bool:
        log.warning(
            "campaign stopping: %s; the probe lifts and parks; finish it with: neatskin campaign resume %s",
            reason,
            self.folder,
        )
        self._flush()
        self._park()
        self._write_state("stopped", reason)
        return False

    def _pause(self, reason: str, *, auto: bool) -> bool:
        self.pauses += 1
        self._flush()
        self._lift()
        self._write_state("paused", reason, auto=auto)
        idle_since = self._clock()  # the lift was the last move
        deadline = idle_since + self.max_pause_s
        while self._clock() < deadline:
            if self._interrupted():
                return self._stop("Ctrl-C (or SIGTERM, SIGHUP) during a pause")
            paused, by = True, ""
            for request in self._new_requests():  # in order: a continue then a pause stay paused
                if request.action == "stop":
                    return self._stop(f"stop requested by {request.by}")
                paused, by = request.action == "pause", request.by
            if not paused:
                log.warning("campaign continues (%s)", by)
                idle_s = self._clock() - idle_since
                if self._rehome is not None and 0 < self.stepper_timeout_s <= idle_s:
                    log.warning(
                        "the pause (%.0f s) outlasted the printer's stepper timeout (%.0f s): homing again first",
                        idle_s,
                        self.stepper_timeout_s,
                    )
                    self._rehome()
                self._missed = []
                self._write_state("running", None)
                return True
            self._sleep(self.poll_s)
        return self._stop(f"paused longer than {self.max_pause_s:.0f} s")

    def finished(self, state: str = "finished") -> None:
        """The press loop ended: every press of this run done ("finished") or stopped ("stopped")."""
        if read_state(self.folder).get("state") != "stopped":
            self._write_state(state, None)

"""The press loop: the plan's presses one at a time on a rig, each labelled by its FSR and handed to the writer in order.

`press_loop` presses every block of `todo` (retrying a press the FSR missed), stops between presses at the
checkpoint (pause, continue, stop, Ctrl-C; neatskin.rig.control) and hands each press's row to the writer. The
recorder's `end` gives each press as a future-like (neatskin.acquisition.record.PendingPress): a press whose
record is done is written at once; one whose pair estimates are still coming (the dry run's skin worker) waits,
up to IN_FLIGHT_PRESSES of them, while the next ones run; every press pressed reaches the writer before any
flush. The loop never asks which rig it has. The runner (neatskin.rig.runner) builds the plan, the folder and
the rig around it.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from types import FrameType
from typing import TYPE_CHECKING, Any

import numpy as np

from neatskin import stopsignals
from neatskin.acquisition.record import PendingPress
from neatskin.datasets.writer import CampaignWriter
from neatskin.gcode.blocks import PressBlock, PressBlocks
from neatskin.rig.assembly import Driver, Rig
from neatskin.rig.control import Checkpoint
from neatskin.rig.plan import Plan
from neatskin.rig.pressrow import fsr_label
from neatskin.rig.protocol import CampaignProtocol
from neatskin.stopsignals import signal_name

if TYPE_CHECKING:  # tqdm is imported when the loop starts (a progress bar, nothing else needs it)
    from tqdm import tqdm

log = logging.getLogger(__name__)
MAX_PRESS_ATTEMPTS = 3  # a press the FSR never saw is retried twice, then stored flagged


class _StopRequest:
    """Ctrl-C, SIGTERM or SIGHUP (neatskin.stopsignals) sets a flag; the press in flight finishes, the probe lifts
    and parks, the campaign stays resumable. A second one stops at once."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: str | None = None  # the first stop signal's name, for the message
        self._handled: contextlib.ExitStack | None = None

    def __enter__(self) -> _StopRequest:
        def handler(signum: int, frame: FrameType | None) -> None:
            if self.requested:  # a second stop signal: stop now
                raise KeyboardInterrupt(f"stopped at once by a second {signal_name(signum)}")
            self.requested, self.signal = True, signal_name(signum)

        self._handled = contextlib.ExitStack()
        self._handled.enter_context(stopsignals.handled(handler))  # not the main thread: signals act as usual
        return self

    def __exit__(self, *exc: object) -> None:
        if self._handled is not None:
            self._handled.close()


class _BarStream:
    """The progress bar's stream: a terminal that went away (a dropped SSH session) fails every write with EIO,
    which is no reason to leave the probe in the skin; the bar then stops showing, the campaign goes on to its
    stop signal (SIGHUP) and parks."""

    def __init__(self, stream: Any) -> None:
        self._stream, self._lost = stream, False

    def write(self, text: str) -> None:
        if not self._lost:
            try:
                self._stream.write(text)
            except OSError:
                self._lost = True

    def flush(self) -> None:
        if not self._lost:
            try:
                self._stream.flush()
            except OSError:
                self._lost = True

    def __getattr__(self, name: str) -> Any:  # isatty, fileno, encoding: what tqdm asks of its stream
        return getattr(self._stream, name)


@dataclass
class _Pressed:
    """A press done on the rig and labelled by its FSR; its record may still be pending (resolved by `_press_row`)."""

    block: Any
    record: PendingPress  # kept: its result() is the whole PressRecord
    label: Any  # rig.pressrow.FsrLabel
    extra_flags: list[str]
    started: datetime
    finished: datetime

    @property
    def label_flags(self) -> list[str]:
        """The flags known before the estimates (the checkpoint needs only "fsr_missed")."""
        return [*self.extra_flags, *self.label.flags]


class _InFlight:
    """The presses pressed but not yet handed to the writer, oldest first, at most `limit` of them: a press whose
    record is not done waits here while the next presses run; a done one is written at once. `settle` writes them
    in press order; every writer flush comes after a settle, so what a pause, a stop or the loop's end shows is
    every press pressed."""

    def __init__(
        self, protocol: CampaignProtocol, writer: CampaignWriter, pair_labels: list[str], bar: tqdm, limit: int
    ) -> None:
        self.protocol, self.writer, self.pair_labels, self.bar, self.limit = protocol, writer, pair_labels, bar, limit
        self.presses: collections.deque[_Pressed] = collections.deque()
        self.written = self.flagged = 0

    def add(self, pressed: _Pressed) -> None:
        self.presses.append(pressed)
        self.settle(keep=self.limit)

    def settle(self, keep: int = 0) -> None:
        """Write the oldest presses while more than `keep` wait, or while the oldest is done."""
        while self.presses and (len(self.presses) > keep or self.presses[0].record.done()):
            row, waveforms = _press_row(self.protocol, self.presses[0], self.pair_labels)
            self.presses.popleft()
            self.writer.write_press(row, waveforms)
            self.written += 1
            self.flagged += bool(row["flags"])
            # the count shows at the bar's next redraw (tqdm's 0.1 s): a redraw per press cost 30 us of the main
            # process's critical path (formatting and a write to the terminal)
            self.bar.set_postfix(flagged=self.flagged, refresh=False)
            self.bar.update(1)

    def flush(self) -> None:
        self.settle()
        self.writer.flush()

    def settle_after_error(self) -> None:
        """On the way out of an error: hand the writer every press whose estimates still come (the error path
        then flushes them); stop at the first that cannot, which resume presses again."""
        try:
            self.settle()
        except Exception as again:
            log.warning("%d pressed presses were not written (resume presses them again): %s", len(self.presses), again)


IN_FLIGHT_PRESSES = 4  # presses whose records may be pending at once (memory stays flat)


def press_loop(
    protocol: CampaignProtocol,
    plan: Plan,
    rig: Rig,
    writer: CampaignWriter,
    todo: PressBlocks,
    pair_labels: list[str],
    already_done: int,
    progress: bool,
) -> tuple[int, int, bool]:
    from tqdm import tqdm

    driver = rig.driver
    driver.send_lines(plan.program.preamble, source="preamble")
    bar = tqdm(
        total=plan.n_presses,
        initial=already_done,
        unit="press",
        disable=not progress,
        desc=f"{protocol.name} ({rig.kind})",
        dynamic_ncols=True,
        file=_BarStream(sys.stderr),
    )
    pending = _InFlight(protocol, writer, pair_labels, bar, IN_FLIGHT_PRESSES)
    interrupted = False
    with _StopRequest() as stop:
        checkpoint = _checkpoint(protocol, plan, driver, writer, stop, flush=pending.flush)
        try:
            for block in todo:
                pressed = _run_press(protocol, plan, rig, block, pair_labels)
                pending.add(pressed)
                if stop.requested and block is todo[-1]:  # the last press is done: the campaign is complete
                    log.warning("%s during the last press: the campaign is complete", stop.signal)
                elif stop.requested:  # Ctrl-C, SIGTERM or SIGHUP: as `campaign stop` does, after this press
                    interrupted = True
                    log.warning(
                        "%s: press %d finished; the probe lifts and parks; finish with: neatskin campaign resume %s",
                        stop.signal,
                        block.press_id,
                        writer.folder,
                    )
                    driver.send_lines(_park_lines(plan), source="stop park")
                    break
                if block is not todo[-1] and not checkpoint.after_press(block.press_id, pressed.label_flags):
                    interrupted = True
                    break
            pending.flush()  # every press of this run is durable before the loop says it ended
        except KeyboardInterrupt as exc:  # a second stop signal: no lift, no park
            pending.settle_after_error()
            try:  # a monitor page shows a stopped campaign, not a running one
                checkpoint.finished("stopped")
            except Exception as lost:  # the interrupt, not this, is what the user must hear
                log.warning("the control state was not written: %s", lost)
            raise KeyboardInterrupt(
                f"{exc or 'stopped at once'}; the probe was not lifted: check the rig, then finish with: "
                f"neatskin campaign resume {writer.folder}"
            ) from None
        except BaseException:
            pending.settle_after_error()
            raise
        checkpoint.finished("stopped" if interrupted else "finished")
    bar.close()
    return pending.written, pending.flagged, interrupted


def _checkpoint(
    protocol: CampaignProtocol,
    plan: Plan,
    driver: Driver,
    writer: CampaignWriter,
    stop: _StopRequest,
    flush: Callable[[], object] | None = None,
) -> Checkpoint:
    """The safe point between presses (neatskin.rig.control): pause lifts and waits, stop lifts and parks;
    both write the presses pressed first (`flush`: those in flight, then the writer's batch), so what a paused
    campaign shows is every press pressed."""
    post = plan.program.postamble  # lift to the safe height, park, lift, M400, done marker
    return Checkpoint(
        writer.folder,
        flush=writer.flush if flush is None else flush,
        lift=lambda: driver.send_lines((*post[:1], "M400"), source="pause lift"),
        park=lambda: driver.send_lines(_park_lines(plan), source="stop park"),
        fsr_miss_limit=protocol.fsr_pause_after_misses,
        interrupted=lambda: stop.requested,
        # a pause that outlasted the stepper timeout: home as the program began, then back up to the safe height
        rehome=lambda: driver.send_lines((*plan.program.preamble, *post[:1], "M400"), source="re-home"),
        stepper_timeout_s=protocol.printer.stepper_timeout_s,
    )


def _park_lines(plan: Plan) -> tuple[str, ...]:
    """Lift to the safe height, park, lift, and wait for the moves (a stop: a request or a stop signal)."""
    post = plan.program.postamble  # lift to the safe height, park, lift, M400, done marker
    return (*post[:3], "M400") if post else ()


def _hold_lines(hold_s: float) -> tuple[str, ...]:
    return (f"G4 P{int(round(hold_s * 1000))}", "M400")


def _run_press(protocol: CampaignProtocol, plan: Plan, rig: Rig, block: PressBlock, pair_labels: list[str]) -> _Pressed:
    """Press one block (retrying a press the FSR missed) and label it; the kept attempt's record is kept (what it
    defers starts) and resolved later (`_press_row`), so the next press runs meanwhile."""
    driver, recorder = rig.driver, rig.recorder
    extra_flags: list[str] = []
    for attempt in range(MAX_PRESS_ATTEMPTS):
        started = datetime.now(UTC)
        for phase in block.phases:
            driver.send_lines(phase.lines, source=f"press {block.press_id} {phase.name}")
            if phase.name == "travel":
                recorder.begin(block.press_id, plan.n_sweeps)
            elif phase.name == "descend":
                recorder.mark("contact")
            elif phase.name == "press":
                recorder.mark("hold_start")
                driver.send_lines(_hold_lines(plan.hold_s), source=f"press {block.press_id} hold")
                recorder.mark("hold_end")
            elif phase.name == "lift":
                recorder.mark("lifted")
        record = recorder.end()
        label = fsr_label(
            record.fsr_v, record.fsr_rate_hz, rig.fsr_model, record.first_sample, record.marks, record.rate_hz
        )
        if not label.missed or attempt == MAX_PRESS_ATTEMPTS - 1:
            break
        extra_flags.append(f"fsr_retry:{attempt + 1}")
    record.keep()  # only the kept attempt: a retried one costs nothing more
    return _Pressed(block, record, label, extra_flags, started, datetime.now(UTC))


def _press_row(
    protocol: CampaignProtocol, pressed: _Pressed, pair_labels: list[str]
) -> tuple[dict[str, Any], dict[str, np.ndarray] | None]:
    """The press's dataset row (and waveforms), its record awaited when it is still pending."""
    record = pressed.record.result()
    values = record.values(pair_labels)
    block, label = pressed.block, pressed.label
    row = {
        "campaign": protocol.name,
        "press_id": block.press_id,
        "position_id": block.position_id,
        "repeat": block.repeat,
        "x_mm": block.x_mm,
        "y_mm": block.y_mm,
        "depth_mm": protocol.press.press.depth_mm,
        "started_at": pressed.started,
        "finished_at": pressed.finished,
        "fsr_onset_s": label.onset_s,
        "fsr_offset_s": label.offset_s,
        "fsr_peak_n": label.peak_n,
        "flags": [*pressed.extra_flags, *label.flags, *values.flags],
        "R_ohm": values.resistance_ohm,
        "dR_ohm": values.delta_r_ohm,
    }
    return row, record.waveforms


def finish_program(rig: Rig, plan: Plan) -> None:
    rig.driver.send_lines(plan.program.postamble, source="postamble")

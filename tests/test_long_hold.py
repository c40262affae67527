"""A press held longer than half its recording is labelled once, at its hold: the FSR baseline's window is taken from
the press's own span (its contact and lifted marks), not detect_presses' default of half the trace, which a long
hold outlasts (every press was flagged `fsr_multiple:2`, `fsr_not_at_hold`). The short hold's rows do not change."""

import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import PROTOCOLS

from neatskin.acquisition.fsr import FsrModel
from neatskin.cli import main
from neatskin.rig.pressrow import baseline_window_s, fsr_label


def _trapezoid(hold_s: float, rate_hz: float, model: FsrModel):
    """An FSR trace laid out like the dry run's: 2 s unloaded, a 0.3 s ramp to 3 N, the hold, a 0.3 s ramp down,
    4.5 s unloaded; its marks (DAQ samples at 10 kHz) where the runner sets them; its force."""
    t = np.arange(int(round((2.0 + 0.3 + hold_s + 0.3 + 4.5) * rate_hz))) / rate_hz
    down = 2.3 + hold_s
    force = 3.0 * np.clip(np.minimum((t - 2.0) / 0.3, (down + 0.3 - t) / 0.3), 0.0, 1.0)
    marks = {"contact": 19_500, "hold_start": 23_000, "hold_end": int(round(down * 10_000))}
    marks["lifted"] = marks["hold_end"] + 27_500
    return model.volts(force), marks, force


@pytest.mark.parametrize("hold_s", [1.2, 3.0, 10.0, 30.0, 1200.0])
def test_a_long_hold_is_one_press_at_its_hold(hold_s):
    """The oracle: the hysteresis on the noiseless force itself, on above 0.5 N, off below 0.25 N (the ramps are
    shorter than the baseline's 100 ms margin plus its 50 ms smoothing: the bridged baseline is 0 N)."""
    model, rate_hz = FsrModel(), 100.0
    volts, marks, force = _trapezoid(hold_s, rate_hz, model)
    label = fsr_label(volts, rate_hz, model, 0, marks, 10_000.0)
    onset = int(np.argmax(force > 0.5))
    offset = onset + int(np.argmax(force[onset:] < 0.25))
    assert label.flags == ()
    assert (label.onset_s, label.offset_s) == (onset / rate_hz, offset / rate_hz)
    assert onset / rate_hz < 2.3 and offset / rate_hz > 2.3 + hold_s  # the hold lies inside the press
    assert label.peak_n == pytest.approx(3.0, rel=1e-9)


def test_the_window_is_the_default_unless_the_press_may_outlast_it():
    marks = {"contact": 20_500, "hold_start": 38_200, "hold_end": 50_200, "lifted": 77_700}
    assert baseline_window_s(8.54, marks, 10_000.0) == pytest.approx(5.72 + 1.0)  # the span beats half the trace
    assert baseline_window_s(20.0, marks, 10_000.0) == 10.0  # half the trace beats the span
    assert baseline_window_s(2.0, {"hold_start": 0}, 10_000.0) == 2.0  # no span marks: the default


def _dry_run(root, hold_s: float):
    """The smoke protocol cut to 2 presses, held hold_s, dry-run without a report: its rows and waveforms."""
    if not (root / "skins").exists():
        for sub in ("skins", "wiring", "printers"):
            shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("count = 6", "count = 2").replace("repeats = 2", "repeats = 1")
    protocol = root / f"hold{hold_s}.toml"
    protocol.write_text(text.replace("hold_s = 1.2", f"hold_s = {hold_s}"))
    out = root / f"run{hold_s}"
    assert main(["campaign", "run", str(protocol), "--dry-run", "--out", str(out), "--no-report"]) == 0
    return pd.read_parquet(out / "presses.parquet"), pd.read_parquet(out / "waveforms")


@pytest.fixture(scope="module")
def short_hold(tmp_path_factory):
    return _dry_run(tmp_path_factory.mktemp("short"), 1.2)[0]


@pytest.mark.parametrize("hold_s", [10, 30])
def test_a_dry_run_with_a_long_hold_labels_every_press_once_at_its_hold(tmp_path, short_hold, hold_s):
    """Against the same presses held 1.2 s (labelled right by the old code): the onset where it was, the offset
    later by the added hold; the onset not before the trace itself is above 0.5 N, the offset where it falls below
    0.25 N (within 10 ms)."""
    rows, waves = _dry_run(tmp_path, hold_s)
    model, rate_hz = FsrModel(), 10_000.0
    assert len(rows) == len(short_hold) == 2
    for row, short in zip(rows.itertuples(), short_hold.itertuples()):
        assert (row.x_mm, row.y_mm) == (short.x_mm, short.y_mm)
        assert [f for f in row.flags if f.startswith("fsr")] == []
        assert row.fsr_onset_s == pytest.approx(short.fsr_onset_s, abs=0.02)
        assert row.fsr_offset_s - (hold_s - 1.2) == pytest.approx(short.fsr_offset_s, abs=0.02)
        fsr_v = waves[waves.press_id == row.press_id].sort_values("sample").fsr_v.to_numpy()
        on, off = (np.flatnonzero(model.newtons(fsr_v) > n) for n in (0.5, 0.25))  # the hysteresis' thresholds
        assert on[0] / rate_hz <= row.fsr_onset_s < row.fsr_onset_s + hold_s < row.fsr_offset_s
        assert row.fsr_offset_s == pytest.approx((off[-1] + 1) / rate_hz, abs=0.01)


def _protocol(root, **replace: str):
    """The smoke protocol with its hardware files under root, its text edited (old: new)."""
    for sub in ("skins", "wiring", "printers"):
        if not (root / sub).exists():
            shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = root / "edited.toml"
    path.write_text(text)
    return path


def test_check_warns_of_a_hold_over_a_minute_but_passes_it(tmp_path, capsys):
    from neatskin.rig.plan import LONG_HOLD_S, build_plan
    from neatskin.rig.protocol import load_protocol

    assert main(["campaign", "check", str(_protocol(tmp_path, **{"hold_s = 1.2": "hold_s = 1200"}))]) == 0
    out = capsys.readouterr().out
    assert "printer time 4.02 h for the 12 presses" in out
    warning = "  warning: hold_s = 1200 s is over 60 s: the holds alone take 4.00 h of the 4.02 h; "
    assert f"{warning}if it was meant in milliseconds, set hold_s = 1.2\n" in out
    for hold, warns in (("1.2", False), (f"{LONG_HOLD_S:g}", False), ("60.5", True)):
        plan = build_plan(load_protocol(_protocol(tmp_path, **{"hold_s = 1.2": f"hold_s = {hold}"})))
        assert (plan.long_hold_warning() is not None) == warns


def test_a_report_that_fails_after_the_recording_says_the_data_is_whole_first(tmp_path, capsys):
    """Every press missed (the skin 5 mm below where it is calibrated): the run records them all, flagged; the
    report then has nothing to learn from (exit 5). The CLI says the data is complete before the report's error,
    whose fix is the command line; from Python the same error names the keyword."""
    from neatskin.errors import DataError
    from neatskin.rig.runner import finish_campaign

    edits = {"count = 6": "count = 2", "repeats = 2": "repeats = 1", "surface_error_mm = 0.0": "surface_error_mm = 5.0"}
    out = tmp_path / "run"
    assert main(["campaign", "run", str(_protocol(tmp_path, **edits)), "--dry-run", "--out", str(out), "--quiet"]) == 5
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"neatskin: error: {out}: the campaign's data is complete and intact (2 of 2 presses in {out}); only its "
        "baseline report failed, for the reason below",
        f"neatskin: error: {out}: [flags]: no presses left to learn from after dropping 2 flagged (fix: record "
        f"presses without flags, or keep them: neatskin baselines {out} --flagged keep)",
    ]
    rows = pd.read_parquet(out / "presses.parquet")
    assert len(rows) == 2 and all("fsr_missed" in list(f) for f in rows["flags"])
    with pytest.raises(DataError) as caught:
        finish_campaign(out, progress=False)
    assert "(fix: record presses without flags, or pass flagged='keep')" in str(caught.value)
    assert "--flagged" not in str(caught.value) and "complete and intact (2 of 2 presses" in str(caught.value)

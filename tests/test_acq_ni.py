"""The NI backend without hardware: the task plan as data, the missing-driver error, and the apply step
against a loop-back fake of the nidaqmx API (a resistor board wired as the plan says)."""

import sys
import types
from pathlib import Path

import numpy as np
import pytest

from neatskin.acquisition.daq import DaqConfig
from neatskin.acquisition.daq.nidaqmx_backend import IDLE_TAIL_SAMPLES, line_bits, pack_lines, plan_acquisition
from neatskin.acquisition.demod import demodulate
from neatskin.acquisition.sequence import build_sweep
from neatskin.acquisition.wiring import load_wiring, sequential_wiring
from neatskin.errors import ConfigError, HardwareError
from neatskin.rig.assembly import open_daq

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"


@pytest.fixture(scope="module")
def wiring(paper_layout):
    return load_wiring(PAPER, paper_layout)


def test_plan_is_exact(wiring):
    sweep = build_sweep(wiring)
    plan = plan_acquisition(DaqConfig(), sweep, n_sweeps=2, start_time_s=1.0)
    n = 2 * sweep.n_samples
    assert (plan.n_data, plan.n_samples) == (n, n + IDLE_TAIL_SAMPLES)
    assert plan.clock_source == "/Dev1/ai/SampleClock"
    assert [(c.physical, c.name, c.min_v, c.max_v) for c in plan.ai] == [
        ("Dev1/ai0", "voltage_v", -10.0, 10.0),
        ("Dev1/ai1", "current_a", -10.0, 10.0),
        ("Dev1/ai2", "fsr_v", -10.0, 10.0),
    ]
    assert plan.do_channel == ",".join(f"Dev1/port0/line{k}" for k in range(9))
    # the default 0.2 mA at 1 V/mA: a 0.2 V sine, 10 samples per period, phase from the global index (start 10000 =
    # whole periods)
    np.testing.assert_allclose(plan.ao_data_v[:10], 0.2 * np.sin(2 * np.pi * np.arange(10) / 10), atol=1e-12)
    assert np.all(plan.ao_data_v[-IDLE_TAIL_SAMPLES:] == 0)
    # port words: sample 0 all inhibited (0x1FC) with the wrap address 3 (A=B=1) -> 0x1FF;
    # sample 1 address 0 -> 0x1FC; sample 2 chip U1 enabled (bit 2 low) -> 0x1F8
    assert plan.do_data[:3].tolist() == [0x1FF, 0x1FC, 0x1F8]
    # pair 5 = chip 1 address 1: bit 0 high, bit 3 low
    live = sweep.live_windows[5, 0]
    assert plan.do_data[live] == 0x1FF & ~(1 << 3) & ~(1 << 1)
    assert np.all(plan.do_data[-IDLE_TAIL_SAMPLES:] & 0x1FC == 0x1FC)  # every chip inhibited at the end
    assert plan.timeout_s == pytest.approx((n + 2) / 1e4 + 5.0)


def test_pack_lines_uses_the_wired_bits():
    lines = np.array([[True, False, True], [False, True, False]])
    assert pack_lines(lines, np.array([4, 0, 31], dtype=np.uint32)).tolist() == [(1 << 4) | (1 << 31), 1]


def test_lines_off_port0_refused(paper_layout):
    lines = ("port1/line0",) + tuple(f"port0/line{k}" for k in range(1, 9))
    sweep = build_sweep(sequential_wiring(paper_layout, lines))
    with pytest.raises(ConfigError, match="'port1/line0' cannot be hardware-timed on the USB-6229"):
        plan_acquisition(DaqConfig(), sweep)
    assert line_bits(("port0/line7",)).tolist() == [7]


def test_rate_beyond_the_device_refused(wiring):
    from neatskin.acquisition.sequence import SweepTiming

    sweep = build_sweep(wiring, SweepTiming(rate_hz=100_000.0))
    with pytest.raises(ConfigError, match="exceed the USB-6229"):
        plan_acquisition(DaqConfig(rate_hz=100_000.0), sweep)


def test_missing_nidaqmx_is_a_clear_hardware_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "nidaqmx", None)  # import fails as if not installed
    with pytest.raises(HardwareError, match=r"pip install 'neatskin-rig\[ni\]'"):
        open_daq("ni")


def test_toolkit_imports_without_nidaqmx():
    import subprocess

    code = (
        "import sys, neatskin.acquisition.daq, neatskin.acquisition.demod, neatskin.acquisition.features, "
        "neatskin.acquisition.cli; assert 'nidaqmx' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---- a loop-back fake of the nidaqmx API ------------------------------------------------------


def fake_nidaqmx(board_ohm, devices=("Dev1",)):
    """AO drives the galvanostat; DO selects the pair; AI reads V, I and 0 V FSR, as the plan wires them."""
    calls = []
    written = {}
    mod = types.ModuleType("nidaqmx")
    constants = types.SimpleNamespace(
        AcquisitionType=types.SimpleNamespace(FINITE="FINITE"),
        LineGrouping=types.SimpleNamespace(CHAN_FOR_ALL_LINES="ALL"),
        TerminalConfiguration=types.SimpleNamespace(DIFF="DIFF"),
    )

    class Channels:
        def __init__(self, task, kind):
            self.task, self.kind = task, kind

        def __getattr__(self, name):
            def add(physical, **kw):
                calls.append((self.task.name, name, physical, kw))

            return add

    class Timing:
        def __init__(self, task):
            self.task = task

        def cfg_samp_clk_timing(self, rate, source=None, sample_mode=None, samps_per_chan=None):
            calls.append((self.task.name, "timing", rate, source, sample_mode, samps_per_chan))

    class Task:
        count = 0

        def __init__(self):
            self.name = ["ai", "ao", "do"][Task.count % 3]
            Task.count += 1
            self.ai_channels = self.ao_channels = self.do_channels = Channels(self, self.name)
            self.timing = Timing(self)
            self.out_stream = self.in_stream = self

        def __enter__(self):
            return self

        def __exit__(self, *a):
            calls.append((self.name, "close"))

        def start(self):
            calls.append((self.name, "start"))

        def wait_until_done(self, timeout):
            calls.append((self.name, "done"))

    class Writer:
        def __init__(self, stream, auto_start):
            self.stream = stream
            assert auto_start is False

        def write_many_sample(self, data):
            written["ao"] = data.copy()

        def write_many_sample_port_uint32(self, data):
            written["do"] = data.copy()

    class Reader:
        def __init__(self, stream):
            pass

        def read_many_sample(self, data, n, timeout):
            words = written["do"]
            current = written["ao"] / 1000.0  # galvanostat: 1 mA per V
            chips_on = (~words >> 2) & 0x7F
            addr = words & 3
            chip = np.where(chips_on > 0, np.log2(np.maximum(chips_on, 1)).astype(int), -1)
            pair = np.where(chip >= 0, 4 * chip + addr, -1)
            r = np.where(pair >= 0, board_ohm[np.maximum(pair, 0)], 0.0)
            current = np.where(pair >= 0, current, 0.0)
            data[0] = current * r * 0.5  # the AI sees half the pair voltage
            data[1] = current * 1000.0
            data[2] = 0.0
            calls.append(("ai", "read", n, timeout))

    mod.Task = Task
    mod.constants = constants
    mod.stream_readers = types.SimpleNamespace(AnalogMultiChannelReader=Reader)
    mod.stream_writers = types.SimpleNamespace(AnalogSingleChannelWriter=Writer, DigitalSingleChannelWriter=Writer)
    mod.system = types.SimpleNamespace(
        System=types.SimpleNamespace(
            local=lambda: types.SimpleNamespace(devices=[types.SimpleNamespace(name=d) for d in devices])
        )
    )
    return mod, calls


def install(monkeypatch, mod):
    monkeypatch.setitem(sys.modules, "nidaqmx", mod)
    for sub in ("constants", "stream_readers", "stream_writers", "system"):
        monkeypatch.setitem(sys.modules, f"nidaqmx.{sub}", getattr(mod, sub))


def test_apply_plan_slaves_ao_do_to_ai_and_round_trips(monkeypatch, wiring):
    board = np.linspace(2_000.0, 8_000.0, 28)
    mod, calls = fake_nidaqmx(board)
    install(monkeypatch, mod)
    sweep = build_sweep(wiring)
    with open_daq("ni", DaqConfig()) as daq:
        acq = daq.acquire(sweep, 2, start_time_s=3.0)
    assert acq.n_samples == 2 * sweep.n_samples and acq.sample_index[0] == 30_000
    est = demodulate(acq, sweep, "lockin")
    np.testing.assert_allclose(est.resistance_ohm, np.broadcast_to(board, (2, 28)), rtol=1e-9)
    timing = {c[0]: c for c in calls if c[1] == "timing"}
    assert timing["ai"][3] is None and timing["ao"][3] == timing["do"][3] == "/Dev1/ai/SampleClock"
    assert {t[5] for t in timing.values()} == {2 * sweep.n_samples + IDLE_TAIL_SAMPLES}
    starts = [c[0] for c in calls if c[1] == "start"]
    assert starts == ["ao", "do", "ai"]  # the slaves wait for the master's clock
    do_chan = [c for c in calls if c[1] == "add_do_chan"][0]
    assert do_chan[2] == ",".join(f"Dev1/port0/line{k}" for k in range(9)) and do_chan[3]["line_grouping"] == "ALL"


def test_no_device_answers(monkeypatch):
    mod, _ = fake_nidaqmx(np.ones(28), devices=("Dev2",))
    install(monkeypatch, mod)
    with pytest.raises(HardwareError, match=r"no NI device 'Dev1' answers \(found: Dev2\)"):
        open_daq("ni", DaqConfig())


def test_open_daq_kinds():
    with pytest.raises(ConfigError, match="unknown DAQ kind 'labjack'"):
        open_daq("labjack")
    with pytest.raises(ConfigError, match="needs pair_resistance_ohm"):
        open_daq("simulated")
    daq = open_daq("simulated", DaqConfig(), pair_resistance_ohm=lambda t: np.ones((len(t), 28)))
    assert daq.config.rate_hz == 10_000.0

"""The monitor server over real HTTP: the snapshot of a finished and of a killed campaign, the token guard on
the controls, loopback-only binding, and path traversal refused (`..`, encoded, absolute, symlinks out)."""

from __future__ import annotations

import http.client
import json
import re
import shutil
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses
from neatskin.errors import ConfigError
from neatskin.monitor.server import make_server, resolve_inside
from neatskin.monitor.state import CampaignView
from neatskin.monitor.wiretail import wire_tail
from neatskin.rig.control import read_request
from neatskin.tomlfile import resolve_path

SMOKE = resolve_path("protocols/smoke.toml")


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path_factory.mktemp("mon") / "smoke"
    run_campaign(load_protocol(SMOKE), folder, progress=False, report=False)
    return folder


@pytest.fixture(scope="module")
def killed(tmp_path_factory) -> Path:
    """A campaign stopped after 5 presses with its manifest still saying running (as a kill -9 leaves it)."""
    from neatskin.datasets.manifest import update_manifest
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path_factory.mktemp("mon") / "killed"
    run_campaign(load_protocol(SMOKE), folder, progress=False, report=False, limit=5)
    update_manifest(folder, status="running")
    return folder


class Served:
    def __init__(self, folder: Path, **kwargs) -> None:
        self.server = make_server(folder, port=0, **kwargs)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def request(self, method: str, path: str, headers: dict | None = None) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        hdrs = {"Host": f"127.0.0.1:{self.port}", **(headers or {})}
        for key, value in hdrs.items():
            conn.putheader(key, value)
        conn.endheaders()
        resp = conn.getresponse()
        body = resp.read()
        conn.close()
        return resp.status, body

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def served(finished):
    s = Served(finished, token="sesame")
    yield s
    s.close()


def test_state_of_a_finished_campaign(served, finished):
    status, body = served.request("GET", "/api/state")
    assert status == 200
    s = json.loads(body)
    df = read_presses(finished)
    assert s["campaign"] == "smoke" and s["status"] == "complete"
    assert s["counts"] == {"done": 12, "planned": 12, "flagged": int(sum(len(f) > 0 for f in df["flags"]))}
    assert s["presses"]["press_id"] == list(range(12))
    assert s["presses"]["x_mm"] == df["x_mm"].tolist()
    last = s["last_press"]
    assert last["press_id"] == 11 and len(last["pairs"]) == 28 and last["pairs"][0] == "1-2"
    np.testing.assert_array_equal(
        last["measured_dr_ohm"], df.iloc[-1][[f"dR_ohm_{p.replace('-', '_')}" for p in last["pairs"]]].to_numpy(float)
    )
    # the ideal model at the press's position: the dry run's skin plus noise, so close but not equal
    measured, expected = np.array(last["measured_dr_ohm"]), np.array(last["expected_dr_ohm"])
    assert np.corrcoef(measured, expected)[0, 1] > 0.99
    base = (
        df[[c for c in df.columns if c.startswith("R_ohm_")]].to_numpy()
        - df[[c for c in df.columns if c.startswith("dR_ohm_")]].to_numpy()
    )
    assert s["drift"]["baseline_first_ohm"] == pytest.approx(base[0].tolist())
    assert s["drift"]["baseline_pct"][0][0] == 0.0 and len(s["drift"]["baseline_pct"]) == 28
    assert s["layout"]["name"] and len(s["layout"]["channels"]) == 12 and len(s["layout"]["electrodes"]) == 8
    assert s["printer"]["source"] == "commanded" and s["printer"]["Z"] == pytest.approx(60.0)  # parked
    # the dry run's printer has ADVANCED_OK, so its oks name the line: `ok N190 P16 B3`
    # the wire log as text (UTC clock, arrow, the line), one line per line on the wire, no b'...' reprs
    assert re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3} ← ok N\d+ P\d+ B\d+", s["wire_tail"][-1]), s["wire_tail"][-1]
    assert re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3} ← echo:NS program=done", s["wire_tail"][-2]), s["wire_tail"][-2]
    assert not any("b'" in line for line in s["wire_tail"])
    assert s["server"] == {
        "controls": True,
        "remote": False,
        "bound_to": "127.0.0.1",
        "terminal": False,
        "printer_port": None,
    }


def test_state_of_a_killed_campaign(killed):
    s = CampaignView(killed).snapshot()
    # the manifest still says running, but no process holds the folder's lock: the page says crashed
    assert s["status"] == "crashed" and s["counts"]["done"] == 5 and s["counts"]["planned"] == 12
    assert s["rate_per_h"] > 0 and s["eta_s"] == pytest.approx(7 / (s["rate_per_h"] / 3600))


def test_view_reads_new_parts_as_they_land(tmp_path, killed):
    folder = tmp_path / "copy"
    shutil.copytree(killed, folder)
    parts = press_parts(folder)
    held = {pid: parts[pid].read_bytes() for pid in (3, 4)}
    for pid in held:
        parts[pid].unlink()
    view = CampaignView(folder)
    assert view.snapshot()["counts"]["done"] == 3
    for pid, data in held.items():
        parts[pid].write_bytes(data)
    assert view.snapshot()["presses"]["press_id"] == [0, 1, 2, 3, 4]


def test_state_of_an_empty_folder(tmp_path):
    s = CampaignView(tmp_path).snapshot()
    assert s["status"] == "unknown" and s["counts"]["done"] == 0 and "no manifest.json" in s["manifest_problem"]
    assert s["last_press"] is None and s["printer"] is None


def test_page_and_assets_are_served_from_the_package(served):
    status, body = served.request("GET", "/")
    assert status == 200 and b'<script src="/assets/app.js"' in body
    assert b"http" not in body.replace(b"http-equiv", b"")  # no external asset
    for name in ("app.js", "style.css"):
        status, body = served.request("GET", f"/assets/{name}")
        assert status == 200 and b"https://" not in body
    assert served.request("GET", "/assets/server.py")[0] == 404


def test_controls_need_the_token(served, finished):
    assert served.request("POST", "/api/control/pause")[0] == 403
    assert served.request("POST", "/api/control/pause", {"X-Neatskin-Token": "wrong"})[0] == 403
    assert read_request(finished) is None
    status, body = served.request("POST", "/api/control/pause", {"X-Neatskin-Token": "sesame"})
    assert status == 409 and b"already complete" in body  # a finished campaign has nothing to pause
    manifest = finished / "manifest.json"
    original = manifest.read_bytes()
    manifest.write_text(json.dumps({**json.loads(original), "status": "running"}))  # as while it runs
    try:
        status, body = served.request("POST", "/api/control/pause", {"X-Neatskin-Token": "sesame"})
    finally:
        manifest.write_bytes(original)
    assert status == 200
    assert read_request(finished).action == "pause" and read_request(finished).by == "monitor page"
    assert served.request("POST", "/api/control/explode", {"X-Neatskin-Token": "sesame"})[0] == 404
    (finished / "control.json").unlink()


def test_read_only_monitor_refuses_every_post(finished):
    s = Served(finished, read_only=True)
    try:
        status, body = s.request("POST", "/api/control/stop", {"X-Neatskin-Token": ""})
        assert status == 403 and b"read-only" in body
        assert json.loads(s.request("GET", "/api/state")[1])["server"]["controls"] is False
    finally:
        s.close()


def test_foreign_host_header_is_refused_on_loopback(served):
    assert served.request("GET", "/api/state", {"Host": "evil.example:80"})[0] == 403


def test_binding_beyond_loopback_needs_allow_remote(finished):
    with pytest.raises(ConfigError, match="--allow-remote"):
        make_server(finished, host="0.0.0.0", port=0)
    server = make_server(finished, host="0.0.0.0", port=0, allow_remote=True)
    try:
        assert server.config.remote
    finally:
        server.server_close()


def test_a_busy_port_is_one_clear_error(finished):
    first = make_server(finished, port=0)
    try:
        with pytest.raises(ConfigError, match=r"cannot listen on 127.0.0.1:\d+.*--port 0 picks a free one"):
            make_server(finished, port=first.server_address[1])
    finally:
        first.server_close()


def test_campaign_files_are_served(served, finished):
    status, body = served.request("GET", "/files/manifest.json")
    assert status == 200 and json.loads(body)["campaign"] == "smoke"
    status, body = served.request("GET", "/files/inputs/protocol.toml")
    assert status == 200 and b'name = "smoke"' in body


@pytest.mark.parametrize(
    "path",
    [
        "/files/../smoke/manifest.json",
        "/files/%2e%2e/%2e%2e/etc/passwd",
        "/files/inputs/..%2f..%2fmanifest.json",
        "/files//etc/passwd",
        "/files/%2fetc%2fpasswd",
        "/../../etc/passwd",
        "/assets/../server.py",
        "/assets/%2e%2e%2fserver.py",
        "/files/%252e%252e/%252e%252e/etc/passwd",
        "/files/outside-link",
        "/files/inputs",
    ],
)
def test_path_traversal_is_refused(served, finished, path):
    outside = finished.parent / "secret.txt"
    outside.write_text("secret")
    link = finished / "outside-link"
    if not link.is_symlink():
        link.symlink_to(outside)
    status, body = served.request("GET", path)
    assert status == 404 and b"secret" not in body and b"root:" not in body


def test_resolve_inside_directly(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "f.txt").write_text("x")
    (tmp_path / "secret").write_text("s")
    (tmp_path / "a" / "up").symlink_to(tmp_path)
    assert resolve_inside(tmp_path / "a", "f.txt") == (tmp_path / "a" / "f.txt").resolve()
    assert resolve_inside(tmp_path / "a", "up/a/f.txt") == (tmp_path / "a" / "f.txt").resolve()  # out and back in
    for rel in ("../a/f.txt", "/etc/passwd", "up/secret", "", "f.txt\x00", "missing.txt"):
        assert resolve_inside(tmp_path / "a", rel) is None, rel


def test_wire_tail_prefers_a_newer_m114_report(tmp_path):
    (tmp_path / "wire.log").write_text(
        "2026-01-01T00:00:00.000000Z     0.1 > b'N7 G0 Z15.5 F300*30\\n'\n"
        "2026-01-01T00:00:00.100000Z     0.2 > b'N8 G0 X97.182 Y112.887 F6000*112\\n'\n"
        "2026-01-01T00:00:00.200000Z     0.3 < b'X:97.18 Y:112.89 Z:15.50 E:0.00 Count X:1 Y:2 Z:3\\nok\\n'\n"
    )
    lines, pos = wire_tail(tmp_path)
    assert len(lines) == 3
    assert pos == {"source": "M114", "X": 97.18, "Y": 112.89, "Z": 15.5, "at": "2026-01-01T00:00:00.200000Z"}
    with open(tmp_path / "wire.log", "a") as f:
        f.write("2026-01-01T00:00:01.000000Z     1.0 > b'N9 G1 Z5.5 F300*25\\n'\n")
    assert wire_tail(tmp_path)[1] == {
        "source": "commanded",
        "X": 97.18,
        "Y": 112.89,
        "Z": 5.5,
        "at": "2026-01-01T00:00:01.000000Z",
    }


def test_wire_tail_reads_every_line_of_a_pipelined_write(tmp_path):
    """Lines sent together (ADVANCED_OK, several in flight) are one wire-log entry: the last move in it counts."""
    (tmp_path / "wire.log").write_text(
        "2026-01-01T00:00:00.000000Z     0.1 > b'N7 G0 Z15.5 F300*30\\nN8 G0 X0 Y200 F6000*68\\nN9 G0 Z60 F300*1\\n"
        "N10 M400*39\\n'\n"
        "2026-01-01T00:00:00.100000Z     0.2 < b'ok N7 P16 B0\\nok N8 P15 B1\\nok N9 P14 B2\\nok N10 P16 B3\\n'\n"
    )
    assert wire_tail(tmp_path)[1] == {
        "source": "commanded",
        "X": 0.0,
        "Y": 200.0,
        "Z": 60.0,
        "at": "2026-01-01T00:00:00.000000Z",
    }


@pytest.mark.slow
@pytest.mark.parametrize("given", [True, False], ids=["port-given", "port-0"])
def test_campaign_run_with_monitor_starts_and_stops_the_page(tmp_path, given):
    """--monitor-port N, or 0: the run picks a free port itself (it must know it to wait for the page)."""
    import os
    import socket
    import subprocess
    import sys

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = tmp_path / "run"
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [sys.executable, "-m", "neatskin", "campaign", "run", str(SMOKE), "--dry-run", "--out", str(out)]
        + ["--no-report", "--quiet", "--monitor", "--monitor-port", str(port if given else 0)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(root), "PYTHONUNBUFFERED": "1"},
    )
    assert proc.returncode == 0, proc.stderr
    if not given:
        port = int(re.search(r"on http://127\.0\.0\.1:(\d+)/", proc.stdout).group(1))
        assert port > 0
    assert f"on http://127.0.0.1:{port}/" in proc.stdout
    assert re.search(r"control token \(paste it in the page to pause/continue/stop\): \S{16,}", proc.stdout)
    assert "campaign complete: 12/12" in proc.stdout
    assert proc.stdout.rstrip().endswith(f"to look again: neatskin monitor {out}")
    with socket.socket() as again:  # the monitor process ended with the campaign: its port is free
        again.bind(("127.0.0.1", port))


def test_seconds_since_the_last_press_tell_a_killed_campaign(killed):
    last = pd.Timestamp(read_presses(killed)["finished_at"].max())
    before = (pd.Timestamp.now(tz="UTC") - last).total_seconds()
    s = CampaignView(killed).snapshot()
    after = (pd.Timestamp.now(tz="UTC") - last).total_seconds()
    assert before <= s["since_last_press_s"] <= after


def test_drift_is_strided_for_long_campaigns(monkeypatch, finished):
    import neatskin.monitor.state as state

    monkeypatch.setattr(state, "DRIFT_MAX_POINTS", 5)
    drift = CampaignView(finished).snapshot()["drift"]
    assert drift["press_id"] == [0, 2, 5, 8, 11]
    assert all(len(col) == 5 for col in drift["baseline_pct"])


def test_a_rewritten_part_rebuilds_the_table(tmp_path, killed):
    folder = tmp_path / "copy"
    shutil.copytree(killed, folder)
    view = CampaignView(folder)
    assert view.snapshot()["counts"]["done"] == 5
    press_parts(folder)[4].unlink()
    assert view.snapshot()["presses"]["press_id"] == [0, 1, 2, 3]


def test_snapshot_json_is_rebuilt_only_when_a_file_changes(tmp_path, killed):
    folder = tmp_path / "copy"
    shutil.copytree(killed, folder)
    view = CampaignView(folder)
    first = view.snapshot_json()
    assert view.snapshot_json() is first  # nothing changed: the same bytes object
    with open(folder / "wire.log", "a") as log:
        log.write("2026-01-01T00:00:00.000000Z     9.9 > b'N999 G0 Z42 F300*1\\n'\n")
    again = json.loads(view.snapshot_json())
    assert again["printer"]["Z"] == 42.0 and again["counts"]["done"] == 5


def test_a_folder_not_made_yet_is_served_and_a_file_is_refused(tmp_path):
    server = make_server(tmp_path / "runs" / "not-yet", port=0)
    try:
        assert CampaignView(tmp_path / "runs" / "not-yet").snapshot()["status"] == "unknown"
    finally:
        server.server_close()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="not a campaign folder"):
        make_server(tmp_path / "file", port=0)

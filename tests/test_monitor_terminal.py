"""The monitor's printer terminal over the simulated printer's real pty: a line with the token reaches the
printer and its reply comes back; without the token, without --printer-port, or while a campaign holds the
folder, it is refused, and a refusal for a campaign lets the port go."""

from __future__ import annotations

import http.client
import json
import threading

import pytest

from neatskin.datasets.lock import CampaignLock
from neatskin.gcode.profile import load_printer_profile
from neatskin.monitor.server import make_server
from neatskin.sim.printer import SimulatedPrinter
from neatskin.tomlfile import resolve_path


@pytest.fixture
def printer():
    sim = SimulatedPrinter(load_printer_profile(resolve_path("protocols/printers/paper.toml")), seed=3)
    port = sim.start_pty()
    yield sim, port
    sim.stop()


def _serve(server):
    if server.terminal is not None:  # the simulated printer does not reboot on open: no banner to wait 5 s for
        server.terminal.connect_timeout_s = 1.0
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    return server


def _post(server, line: str, token: str | None = "sesame") -> tuple[int, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=30)
    headers = {"Content-Type": "application/json", **({"X-Neatskin-Token": token} if token else {})}
    conn.request("POST", "/api/printer", body=json.dumps({"line": line}), headers=headers)
    response = conn.getresponse()
    return response.status, json.loads(response.read())


def test_a_line_reaches_the_printer_and_its_reply_comes_back(printer, tmp_path):
    sim, port = printer
    server = _serve(make_server(tmp_path, port=0, token="sesame", printer_port=port))
    try:
        status, body = _post(server, "G28")
        assert status == 200 and body["line"] == "G28" and body["port"] == port
        status, body = _post(server, "M114")
        assert status == 200 and body["reply"] and "X" in body["reply"][0]
        sent = [text for _, text in sim.executed]
        assert any(t.startswith("G28") for t in sent) and any(t.startswith("M114") for t in sent)
        assert _post(server, "M114", token=None)[0] == 403
        assert _post(server, "M114", token="wrong")[0] == 403
        assert _post(server, "")[0] == 409  # an empty line is refused with a hint, not sent
    finally:
        server.shutdown()
        server.server_close()


def test_refused_while_a_campaign_holds_the_folder_and_the_port_is_let_go(printer, tmp_path):
    sim, port = printer
    server = _serve(make_server(tmp_path, port=0, token="sesame", printer_port=port))
    try:
        assert _post(server, "M114")[0] == 200 and server.terminal.connected
        before = len(sim.executed)
        with CampaignLock(tmp_path):  # a campaign runs in this folder (paused or not, it owns the printer)
            status, body = _post(server, "G28")
            assert status == 409 and "the campaign holds the printer" in body["error"]
            assert not server.terminal.connected  # the port is free for the campaign
        assert len(sim.executed) == before  # nothing reached the printer
        assert _post(server, "M114")[0] == 200  # the campaign ended: the terminal works again
    finally:
        server.shutdown()
        server.server_close()


def test_no_terminal_without_a_printer_port_or_on_a_read_only_monitor(tmp_path, printer):
    _, port = printer
    for kwargs in ({"token": "sesame"}, {"read_only": True, "printer_port": port}):
        server = _serve(make_server(tmp_path, port=0, **kwargs))
        try:
            status, body = _post(server, "M114")
            assert status == 404 and "--printer-port" in body["error"]
        finally:
            server.shutdown()
            server.server_close()


def test_wire_text_decodes_each_entry_into_lines_with_a_utc_clock():
    from neatskin.monitor.wiretail import wire_text

    lines = [
        "2026-11-25T19:07:55.801105Z     0.228258 > b'N1 G21*27\\nN2 G90*18\\n'",
        "2026-11-25T19:07:55.801513Z     0.228665 < b'ok N1 P16 B0\\necho:caf\\xc3\\xa9\\n'",
        "not a wire log entry",
    ]
    assert wire_text(lines) == [
        "19:07:55.801 → N1 G21*27",
        "19:07:55.801 → N2 G90*18",
        "19:07:55.801 ← ok N1 P16 B0",
        "19:07:55.801 ← echo:café",
        "not a wire log entry",
    ]


def test_result_links_name_the_report_and_plots_that_exist(tmp_path):
    from neatskin.monitor.state import result_links

    assert result_links(tmp_path) == []
    (tmp_path / "report.md").write_text("# Baseline report")
    (tmp_path / "baselines_error_vs_time.png").write_bytes(b"\x89PNG")
    assert result_links(tmp_path) == [
        {"name": "report.md", "href": "/files/report.md"},
        {"name": "baselines_error_vs_time.png", "href": "/files/baselines_error_vs_time.png"},
    ]

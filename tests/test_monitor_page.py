"""The monitor page in the real headless Chromium, as a technician reads it: the wire log as text, the model
reference explained, drift lines named, readable ticks, links to the report and plots when done, one clock, and
the printer terminal (a line with the token and its reply; refused while a campaign holds the folder)."""

from __future__ import annotations

import threading

import pytest
from test_monitor_browser import SMOKE, _text, _wait, browser  # noqa: F401 (the fixture)

from neatskin.datasets.lock import CampaignLock
from neatskin.gcode.profile import load_printer_profile
from neatskin.monitor.server import make_server
from neatskin.sim.printer import SimulatedPrinter
from neatskin.tomlfile import resolve_path

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path_factory.mktemp("page") / "smoke"
    with pytest.warns(UserWarning):  # 12 presses: the report warns about its few test rows
        run_campaign(load_protocol(SMOKE), folder, progress=False, report=True)
    return folder


def test_the_finished_page_reads_as_text_with_links_named_lines_and_one_clock(browser, finished):  # noqa: F811
    server = make_server(finished, port=0, token="sesame")
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.1:{server.server_address[1]}/?poll=200#token=sesame")
        _wait(lambda: _text(browser, "done") == "12", what="the page to load the campaign")
        wire = _text(browser, "wire")
        assert "b'" not in wire and "→ N" in wire and "← ok N" in wire
        links = browser.find_elements("css selector", "#resultlinks a")
        names = [a.text for a in links]
        assert "report.md" in names and "baselines_error_vs_time.png" in names
        report = browser.execute_async_script(
            "const done = arguments[arguments.length - 1]; fetch(arguments[0]).then(r => r.text()).then(done);",
            next(a.get_attribute("href") for a in links if a.text == "report.md"),
        )
        assert report.startswith("# Baseline report")
        titles = browser.execute_script(
            "return [...document.querySelectorAll('#drift polyline')].map(p => p.querySelector('title').textContent)"
        )
        assert len(titles) == 28 and all(t.startswith("pair ") for t in titles)
        named = browser.find_elements("css selector", "#drift text[data-label]")
        assert len(named) == 5
        sizes = browser.execute_script(
            "return [...document.querySelectorAll('#drift text, #bars text')]"
            ".map(t => { const m = t.getScreenCTM(); return [t.textContent, parseFloat(t.getAttribute('font-size')) * Math.hypot(m.a, m.b)]; })"
        )
        assert sizes and min(px for _, px in sizes) >= 10.0, sizes  # the smallest label, in CSS pixels
        assert _text(browser, "updated").endswith("UTC") and "times UTC" in browser.page_source
        assert "ideal skin model" in _text(browser, "modellegend")
        # the page's least-squares factor for the model's bars: exact on a model that is the measured / 2
        assert browser.execute_script("return modelScale([2, 4, null, -6], [1, 2, 7, -3])") == 2
        assert browser.execute_script("return modelScale([1, 2], [null, null])") is None
        assert "nothing of the rig" in _text(browser, "modelnote")
    finally:
        server.shutdown()
        server.server_close()


def test_the_printer_terminal_sends_a_line_and_shows_the_reply(browser, tmp_path):  # noqa: F811
    printer = SimulatedPrinter(load_printer_profile(resolve_path("protocols/printers/paper.toml")), seed=5)
    port = printer.start_pty()
    folder = tmp_path / "idle"
    folder.mkdir()
    server = make_server(folder, port=0, token="sesame", printer_port=port)
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.1:{server.server_address[1]}/?poll=200#token=sesame")
        _wait(lambda: port in _text(browser, "terminalstate"), what="the terminal to be offered")
        line = browser.find_element("id", "terminalline")
        for command in ("G28", "M114"):
            line.send_keys(command)
            browser.find_element("id", "terminalsend").click()
            _wait(lambda c=command: f"→ {c}" in _text(browser, "terminalout"), what=f"{command}'s reply")
        out = _text(browser, "terminalout")
        assert "←" in out.split("→ M114", 1)[1]  # the printer's reply under the line
        assert any(text.startswith("M114") for _, text in printer.executed)
        with CampaignLock(folder):
            line.send_keys("G28")
            browser.find_element("id", "terminalsend").click()
            _wait(lambda: "refused (409)" in _text(browser, "terminalout"), what="the refusal")
        assert "the campaign holds the printer" in _text(browser, "terminalout")
    finally:
        server.shutdown()
        server.server_close()
        printer.stop()

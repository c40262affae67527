"""The monitor page in a real headless Chromium (Debian's chromium + chromedriver, driven by Selenium; nothing
downloaded): it follows a dry-run campaign as presses land, pauses it from the page at the next safe point and
continues it to rows identical to an uninterrupted run, and refuses the controls without the token."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from neatskin.datasets.paths import press_parts
from neatskin.datasets.reader import read_presses
from neatskin.tomlfile import resolve_path

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
SMOKE = resolve_path("protocols/smoke.toml")
ROOT = Path(__file__).resolve().parents[1]

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install selenium)")
if not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)):
    pytest.skip(
        "needs Debian's chromium and chromium-driver (/usr/bin/chromium, /usr/bin/chromedriver): "
        "apt-get install chromium chromium-driver",
        allow_module_level=True,
    )


@pytest.fixture
def browser():
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="neatskin-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
        "--window-size=1400,1500",
    ):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}


def _start_monitor(folder: Path, token: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "neatskin", "monitor", str(folder), "--port", "0", "--token", token],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_env(),
    )
    assert proc.stdout is not None
    first = proc.stdout.readline()
    match = re.search(r"on (http://127\.0\.0\.1:\d+/)", first)
    assert match, first
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # drain
    return proc, match.group(1)


def _text(driver, element_id: str) -> str:
    return driver.find_element("id", element_id).text


def _wait(predicate, timeout_s: float = 120.0, what: str = "condition"):
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def _reference(tmp_path: Path):
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    run_campaign(load_protocol(SMOKE), tmp_path / "reference", progress=False, report=False)
    return read_presses(tmp_path / "reference")


def test_page_follows_a_dry_run_and_pauses_and_continues_it(browser, tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    monitor, url = _start_monitor(folder, "sesame")
    campaign = None
    try:
        browser.get(url + "?poll=100#token=sesame")
        assert _text(browser, "status") == "unknown"  # no manifest yet: the page says so, it does not fail
        campaign = subprocess.Popen(
            [sys.executable, "-m", "neatskin", "campaign", "run", str(SMOKE), "--dry-run", "--out", str(folder)]
            + ["--no-report", "--quiet"],
            env=_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        seen: list[int] = []

        def page_done() -> int:
            value = int(_text(browser, "done") or 0)
            if not seen or seen[-1] != value:
                seen.append(value)
            return value

        paused_at = []
        for _ in range(2):  # pause twice from the page: each stops at the next safe point
            _wait(lambda: _text(browser, "status") == "running" and "paused" not in _text(browser, "runner"))
            browser.find_element("id", "pause").click()
            _wait(lambda: "requested" in _text(browser, "controlmsg"), what="the pause to be accepted")
            _wait(lambda: _text(browser, "runner") == "runner: paused", what="the runner to pause")
            parts = len(press_parts(folder))
            _wait(lambda n=parts: page_done() == n, what="the page to show every durable press")
            assert campaign.poll() is None and len(press_parts(folder)) == parts  # nothing moves while paused
            assert "pause requested by monitor page" in _text(browser, "reason")
            paused_at.append(parts)
            browser.find_element("id", "continue").click()
            _wait(lambda: "runner: running" in _text(browser, "runner") or _text(browser, "status") == "complete")
        assert campaign.wait(120) == 0
        _wait(lambda: _text(browser, "status") == "complete" and page_done() == 12, what="the page to show 12/12")
        assert _text(browser, "planned") == "12" and _text(browser, "eta") == "done"
    finally:
        if campaign is not None and campaign.poll() is None:
            campaign.kill()
        monitor.terminate()
        monitor.wait(30)
    assert 1 <= paused_at[0] < paused_at[1] < 12
    assert seen == sorted(seen) and paused_at[0] in seen and paused_at[1] in seen and seen[-1] == 12
    ran, ref = read_presses(folder), _reference(tmp_path)
    cols = ["press_id", "position_id", "x_mm", "y_mm"] + [c for c in ref.columns if c.startswith("dR_ohm_")]
    assert len(ran) == len(ref) == 12
    np.testing.assert_array_equal(ran[cols].to_numpy(), ref[cols].to_numpy())


def test_controls_without_the_token_are_refused(browser, tmp_path):
    from neatskin.monitor.server import make_server
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path / "done"
    run_campaign(load_protocol(SMOKE), folder, progress=False, report=False, limit=3)
    server = make_server(folder, port=0, token="sesame")
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.1:{server.server_address[1]}/?poll=100")
        _wait(lambda: _text(browser, "done") == "3", what="the page to load the campaign")
        for action in ("pause", "stop"):
            browser.find_element("id", action).click()
            _wait(lambda: "refused" in _text(browser, "controlmsg"), what="the refusal")
            assert "refused (403)" in _text(browser, "controlmsg")
            browser.execute_script("document.getElementById('controlmsg').textContent = ''")
        browser.find_element("id", "token").send_keys("wrong-token")
        browser.find_element("id", "pause").click()
        _wait(lambda: "refused (403)" in _text(browser, "controlmsg"), what="the refusal")
        assert not (folder / "control.json").exists()
    finally:
        server.shutdown()
        server.server_close()


def test_page_says_when_it_is_served_beyond_loopback(browser, tmp_path):
    from neatskin.monitor.server import make_server
    from neatskin.rig.protocol import load_protocol
    from neatskin.rig.runner import run_campaign

    folder = tmp_path / "done"
    run_campaign(load_protocol(SMOKE), folder, progress=False, report=False, limit=1)
    for host, remote in (("127.0.0.1", False), ("0.0.0.0", True)):
        server = make_server(folder, host=host, port=0, allow_remote=remote)
        threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
        try:
            browser.get(f"http://127.0.0.1:{server.server_address[1]}/?poll=100")
            _wait(lambda: _text(browser, "done") == "1", what="the page to load the campaign")
            banner = browser.find_element("id", "remote")
            assert banner.is_displayed() is remote
            if remote:
                assert "served on 0.0.0.0 (--allow-remote): anyone who can reach that address" in banner.text
        finally:
            server.shutdown()
            server.server_close()

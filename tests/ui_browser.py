"""`apmcal ui` as a user meets it, for the browser tests (not a test module): the command run as
a program of its own, and a real browser — Debian's headless Chromium driven by Selenium through
its chromedriver — on its page.

Screenshots of each screen go into one folder per test run (APMCAL_UI_SCREENSHOTS, which
tests/conftest.py sets to <tmp>/apmcal-ui-screenshots-<time> unless given), named after the
test; the test run's summary names the folder.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic",
         "--window-size=1280,1000"]
SHOTS = Path(os.environ.get("APMCAL_UI_SCREENSHOTS",
                            Path(tempfile.gettempdir()) / "apmcal-ui-screenshots"))


def browser_missing() -> str | None:
    """Why no browser test can run here, or None."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium not installed (pip install '.[test]')"
    if CHROMIUM is None or CHROMEDRIVER is None:
        return ("headless Chromium and its chromedriver not installed (.ci/run installs "
                "Debian's chromium and chromium-driver)")
    return None


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class UiServer:
    """``apmcal ui --no-browser`` running in ``folder``; its address (with token) and port."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.port = free_tcp_port()
        self.output = open(folder / "apmcal-ui-output.txt", "w+")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "apmcal", "ui", "--no-browser", "--port", str(self.port)],
            cwd=folder, stdout=self.output, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 30
        while not (m := re.search(r"open (http://\S+)", self.text())):
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"apmcal ui did not start: {self.text()}")
            time.sleep(0.05)
        self.url = m.group(1)
        self.token = self.url.split("token=")[1]
        self.base = f"http://127.0.0.1:{self.port}"

    def text(self) -> str:
        self.output.flush()
        return (self.folder / "apmcal-ui-output.txt").read_text()

    def interrupt(self, timeout_s: float = 30) -> int:
        """Ctrl-C, as a user stops it; its exit status."""
        self.process.send_signal(signal.SIGINT)
        return self.process.wait(timeout_s)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)
        self.output.close()


def chromium(profile: Path, downloads: Path):
    """A fresh headless Chromium (its own profile) that saves downloads into ``downloads``."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = CHROMIUM
    for flag in FLAGS + [f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    options.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                              "download.prompt_for_download": False})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.execute_cdp_cmd("Page.setDownloadBehavior", {"behavior": "allow",
                                                        "downloadPath": str(downloads)})
    return driver


class Page:
    """The browser on the page: waits, reads, clicks, screenshots."""

    def __init__(self, driver, test_name: str):
        self.d = driver
        self.name = re.sub(r"[^\w.-]+", "_", test_name)
        self.shots = 0

    def find(self, css: str):
        from selenium.webdriver.common.by import By

        return self.d.find_element(By.CSS_SELECTOR, css)

    def all(self, css: str):
        from selenium.webdriver.common.by import By

        return self.d.find_elements(By.CSS_SELECTOR, css)

    def text(self, css: str) -> str:
        found = self.all(css)
        return found[0].text if found else ""

    def visible(self, css: str) -> bool:
        found = self.all(css)
        return bool(found) and found[0].is_displayed()

    def click(self, css: str) -> None:
        self.find(css).click()

    def type(self, css: str, text: str) -> None:
        box = self.find(css)
        box.clear()
        box.send_keys(text)

    def wait(self, condition, what: str, timeout_s: float = 60.0):
        """Until ``condition()`` is truthy; on timeout, fail saying what the page showed."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                value = condition()
            except Exception:       # the element is being redrawn
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                self.screenshot(f"timeout-{what}")
                errors = [e.text for e in self.all(".error") if e.is_displayed()]
                messages = self.text("#messages")[-1500:]
                pytest.fail(f"page: {what} not within {timeout_s:g} s; errors shown: {errors}; "
                            f"messages: {messages}")
            time.sleep(0.1)

    def screenshot(self, what: str) -> Path:
        """The whole page, as tall as it is, into :data:`SHOTS`."""
        SHOTS.mkdir(parents=True, exist_ok=True)
        self.shots += 1
        height = self.d.execute_script("return document.documentElement.scrollHeight")
        self.d.set_window_size(1280, max(800, min(int(height) + 40, 6000)))
        label = re.sub(r"[^\w.-]+", "_", what)
        path = SHOTS / f"{self.name}-{self.shots:02d}-{label}.png"
        self.d.save_screenshot(str(path))
        self.d.set_window_size(1280, 1000)
        return path


def get(ui, path: str, headers: dict | None = None, data: bytes | None = None,
        method: str | None = None) -> tuple[int, str]:
    """A request as another program (or page) would send it: status and body."""
    req = urllib.request.Request(ui.base + path, data=data, headers=headers or {}, method=method)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def element_shot(page: Page, css: str, what: str) -> Path:
    """One element of the page alone, into :data:`SHOTS` (docs/ui.png is one)."""
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.shots += 1
    path = SHOTS / f"{page.name}-{page.shots:02d}-{what}.png"
    page.d.set_window_size(1280, 6000)          # all of it in view
    page.d.execute_script("arguments[0].scrollIntoView()", page.find(css))
    page.find(css).screenshot(str(path))
    page.d.set_window_size(1280, 1000)
    return path

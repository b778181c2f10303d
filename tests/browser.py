"""Headless Chromium and `mechdsl view` for the browser tests and the view's benchmark:
Debian's chromium and chromedriver driven by selenium, with the flags this closed network
needs (no background connections), and the view started as a user starts it."""

import os
import re
import signal
import subprocess
import sys
import time

CHROMIUM, DRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


def chromium(width: int = 1400, height: int = 1000):
    """A headless Chromium session (selenium's WebDriver)."""
    assert os.path.exists(CHROMIUM) and os.path.exists(DRIVER), \
        "the browser tests need Debian's chromium and chromium-driver (apt-get install)"
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync",
                 f"--window-size={width},{height}"):
        opts.add_argument(flag)
    return webdriver.Chrome(service=Service(DRIVER), options=opts)


class Viewer:
    """`mechdsl view FILE --no-browser` in a child process, and its URL (the browser tests,
    the view's benchmark and its fuzzer): ``url``, its ``host`` (127.0.0.1:PORT) and
    ``token``, the page's ``origin`` and the WebSocket's ``socket_url``."""

    def __init__(self, path, *extra: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "mechdsl", "view", str(path),
                                      "--no-browser", *extra], stderr=subprocess.PIPE,
                                     text=True)
        line = self.proc.stderr.readline()
        found = re.search(r"(http://(127\.0\.0\.1:\d+)/([\w-]+)/)", line)
        assert found, line + self.proc.stderr.read()
        self.url, self.host, self.token = found.groups()
        self.origin = f"http://{self.host}"
        self.socket_url = f"ws://{self.host}/{self.token}/ws"

    def stop(self, timeout: float = 20.0) -> int:
        """Ctrl-C, and the exit status (-1: killed after ``timeout`` s); what the view
        printed on its standard error is kept in :attr:`errors`."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return -1
        finally:
            self.errors = self.proc.stderr.read()
            self.proc.stderr.close()


def wait_for(driver, script: str, timeout: float = 20.0):
    """The value of ``script`` once it is truthy (AssertionError after ``timeout`` s)."""
    end = time.monotonic() + timeout
    while True:
        value = driver.execute_script(script)
        if value or time.monotonic() > end:
            assert value, f"timed out waiting for: {script}"
            return value
        time.sleep(0.02)


READY = ("return window.mechdslView && window.mechdslView.header && "
         "window.mechdslView.header.type === 'run'")

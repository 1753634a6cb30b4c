"""Headless Chromium (Debian's `chromium` package) driven over the DevTools protocol on a pipe: open a
page, wait until a condition in the page holds (in real time: model-viewer decodes in workers, which
Chromium's --virtual-time-budget does not wait for), take a screenshot. Pages are served from a folder
by a loopback HTTP server (browsers do not let a file:// page load its model).

Chromium is not installed by `make test`: the tests that need it skip saying
`apt-get update && apt-get install chromium`.
"""

from __future__ import annotations

import base64
import functools
import http.server
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pytest

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


def chromium_or_skip() -> str:
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("headless Chromium is not installed: apt-get update && apt-get install chromium (Debian), "
                "then run the test again")


@contextmanager
def served(folder: Path) -> Iterator[str]:
    """http://127.0.0.1:PORT/ serving `folder` while the block runs."""
    handler = functools.partial(QuietHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".wasm": "application/wasm",
                      ".glb": "model/gltf-binary"}

    def log_message(self, *args):  # no request lines in the test output
        pass


class Browser:
    """One headless Chromium process; `call` sends a DevTools command and returns its result."""

    def __init__(self, executable: str, width: int = 800, height: int = 600) -> None:
        self.profile = tempfile.TemporaryDirectory(prefix="vortx_chromium_")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        command = [executable, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--no-first-run",
                   "--enable-unsafe-swiftshader", "--use-angle=swiftshader", f"--window-size={width},{height}",
                   f"--user-data-dir={self.profile.name}", "about:blank"]
        # The DevTools pipe is the browser's file descriptors 3 (in) and 4 (out).
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL, pass_fds=(3, 4),
                                        preexec_fn=lambda: (os.dup2(to_browser_r, 3), os.dup2(from_browser_w, 4)))
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._next, self._buffer, self.session = 0, b"", None
        targets = self.call("Target.getTargets")["targetInfos"]
        page = next(t["targetId"] for t in targets if t["type"] == "page")
        self.session = self.call("Target.attachToTarget", targetId=page, flatten=True)["sessionId"]
        self.call("Page.enable")

    def call(self, method: str, timeout_s: float = 60, **params):
        self._next += 1
        message = {"id": self._next, "method": method, "params": params}
        if self.session and not method.startswith("Target."):
            message["sessionId"] = self.session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._next:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply.get("result", {})
            chunk = os.read(self._from_browser, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed its DevTools pipe")
            self._buffer += chunk
        raise TimeoutError(f"{method}: no answer in {timeout_s} s")

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = 90):
        """Poll `expression` until it is truthy; -> its value (None at the time limit)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.25)
        return None

    def screenshot(self, path: Path) -> Path:
        path.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))
        return path

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=10)
        except Exception:
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._to_browser)
        os.close(self._from_browser)
        self.profile.cleanup()


@contextmanager
def browser(width: int = 800, height: int = 600) -> Iterator[Browser]:
    instance = Browser(chromium_or_skip(), width, height)
    try:
        yield instance
    finally:
        instance.close()


def screenshot_page(url: str, path: Path, ready: str, width: int = 800, height: int = 600,
                    timeout_s: float = 90, settle_s: float = 1.0):
    """Open `url`, wait until `ready` (a JavaScript expression) is truthy, screenshot to `path`.
    -> the value of `ready` (None when it never held)."""
    with browser(width, height) as chrome:
        chrome.call("Page.navigate", url=url)
        value = chrome.wait_for(ready, timeout_s)
        time.sleep(settle_s)  # a frame or two after the model's load event
        chrome.screenshot(path)
        return value

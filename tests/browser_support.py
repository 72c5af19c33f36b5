"""Headless Chromium driven over the Chrome DevTools Protocol (CDP) from Python, for the tests
of the HTML report in a real browser.

CDP is spoken over one WebSocket (the ``websockets`` package the live view's test uses too): no
Node, no npm package tree, no browser download — the system's Chromium (Debian ``chromium``).
:func:`chromium` finds it; where it is missing the test skips, except under ``LABRUNNER_CI=1``,
where it fails.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tooling import missing
from websockets.sync.client import connect

NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = (
    "--headless",
    "--no-sandbox",  # root in a container has no user namespace for the sandbox
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",  # a container's small /dev/shm crashes the renderer otherwise
    "--remote-debugging-port=0",  # any free port; Chromium writes it to DevToolsActivePort
)


def chromium() -> str:
    """The Chromium executable; skip without one, fail without one under ``LABRUNNER_CI=1``."""
    for name in NAMES:
        found = shutil.which(name)
        if found:
            return found
    missing(f"no Chromium ({', '.join(NAMES)}) on PATH: `apt-get install -y chromium`")


class Page:
    """One page's CDP session: :meth:`call` a method, :attr:`events` every event received."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.events: list[dict[str, Any]] = []
        self._id = 0

    def call(self, method: str, timeout: float = 30.0, **params: Any) -> dict[str, Any]:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        end = time.monotonic() + timeout
        while True:
            message = json.loads(self.ws.recv(timeout=max(0.0, end - time.monotonic())))
            if message.get("id") == self._id:
                if "error" in message:
                    raise AssertionError(f"{method}: {message['error']}")
                return message["result"]
            self.events.append(message)

    def wait_for(self, event: str, timeout: float = 30.0) -> dict[str, Any]:
        end = time.monotonic() + timeout
        while True:
            for message in self.events:
                if message.get("method") == event:
                    return message
            self.events.append(json.loads(self.ws.recv(timeout=max(0.0, end - time.monotonic()))))

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (JSON-serialisable)."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise AssertionError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and failed loads the page reported so far."""
        with contextlib.suppress(TimeoutError):  # collect what is already on its way
            while True:
                self.events.append(json.loads(self.ws.recv(timeout=0.2)))
        out = []
        for e in self.events:
            method, params = e.get("method"), e.get("params", {})
            if method == "Runtime.exceptionThrown":
                out.append(json.dumps(params["exceptionDetails"])[:500])
            elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                out.append(json.dumps(params.get("args"))[:500])
            elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
                out.append(f"{params['entry'].get('text')} {params['entry'].get('url', '')}")
        return out


@contextlib.contextmanager
def open_page(url: str, profile: Path, timeout: float = 60.0) -> Iterator[Page]:
    """Headless Chromium (a fresh profile in ``profile``) showing ``url``, loaded, with the
    Page, Runtime and Log domains enabled before it loaded."""
    profile.mkdir(parents=True, exist_ok=True)
    process = subprocess.Popen(
        [chromium(), *FLAGS, f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        port_file = profile / "DevToolsActivePort"
        end = time.monotonic() + timeout
        while not (port_file.is_file() and len(port_file.read_text().split()) >= 2):
            if process.poll() is not None or time.monotonic() > end:
                raise AssertionError(f"Chromium did not start its DevTools endpoint (exit {process.poll()})")
            time.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        with connect(f"ws://127.0.0.1:{port}{port_file.read_text().split()[1]}", max_size=None) as browser:
            root = Page(browser)
            target = root.call("Target.createTarget", url="about:blank")["targetId"]
        page_ws = f"ws://127.0.0.1:{port}/devtools/page/{target}"
        with connect(page_ws, max_size=None, open_timeout=timeout) as ws:
            page = Page(ws)
            for domain in ("Page", "Runtime", "Log"):
                page.call(f"{domain}.enable")
            page.call("Page.navigate", url=url)
            page.wait_for("Page.loadEventFired", timeout)
            yield page
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()

"""Debian's chromium, headless, driven by Playwright for Python (never a browser that
Playwright downloads): what the ``browser`` tests use."""

from __future__ import annotations

import http.server
import os
import shlex
import shutil
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from tests.procs import descendants

CHROMIUM_ARGS = [
    "--no-sandbox",  # root in CI
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",  # this machine has no network: no lookups at start
    "--disable-component-update",
    "--disable-sync",
]

REBIND = "rebind.test"
"""A name the browser resolves to 127.0.0.1 (``--host-resolver-rules``): a DNS
rebinding, as a page of the web would make it."""
WITHOUT_PRIVATE_NETWORK_ACCESS = (
    "--disable-features=BlockInsecurePrivateNetworkRequests,"
    "PrivateNetworkAccessSendPreflights,PrivateNetworkAccessRespectPreflightResults,"
    "LocalNetworkAccessChecks"
)
"""Chromium refuses some pages' requests to loopback by itself (Private Network
Access); other browsers do not, and our servers must not count on it: the hostile-page
tests turn it off, so that every request of their pages does reach the server."""


class OtherSite:
    """Another origin: a plain HTTP server on another port of 127.0.0.1 serving fixed
    pages (``{path: html}``); :meth:`close` ends it (its thread joined within
    ``timeout_s``)."""

    def __init__(self, pages: dict[str, str], timeout_s: float = 30.0) -> None:
        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                body = pages.get(self.path, "").encode()
                self.send_response(200 if body else 404)
                self.send_header("Content-Type", "text/html")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.timeout_s = timeout_s
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()
        self.origin = f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(self.timeout_s)


BROWSER_NICE = 10
"""The browser's nice value (at least): it stands for an operator's browser, which must
not take the CPU from the stack it watches. Started at the tests' own priority (nice -10
in the test command), its start and its drawing held both cores beside a mission: every
program of the stack at normal priority stalled 340-500 ms at once, and the pty's
kernel worker with them, so the link fell silent (docs/realtime.md, Known limits)."""


def chromium_path() -> str | None:
    """The system Chromium (``$ROVER_CHROMIUM``, else ``chromium`` on the PATH)."""
    return os.environ.get("ROVER_CHROMIUM") or shutil.which("chromium")


@contextmanager
def chromium(extra_args: tuple[str, ...] = ()) -> Iterator[Any]:
    """A headless Chromium browser (Playwright's ``Browser``; ``extra_args`` after
    :data:`CHROMIUM_ARGS`); skips, saying why, where Chromium or Playwright is missing.
    Closed (the browser and Playwright's driver process ended) on exit."""
    path = chromium_path()
    if path is None:
        pytest.skip("no chromium: apt-get install chromium (bash .ci/bootstrap --test does)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("no playwright for Python: pip install -e '.[test]'")
    with tempfile.TemporaryDirectory(prefix="rover-chromium-") as tmp:
        launcher = _at_browser_nice(path, Path(tmp))
        with sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path=launcher, headless=True, args=[*CHROMIUM_ARGS, *extra_args]
            )
            try:
                _check_niced()
                yield browser
            finally:
                browser.close()


def _at_browser_nice(path: str, directory: Path) -> str:
    """A launcher in ``directory`` that runs ``path`` at :data:`BROWSER_NICE` or above
    (``nice`` adds to the caller's value) and, as root, without ``CAP_SYS_NICE``:
    Chromium lowers the nice of its own processes where it may (to -8, as root), and
    without that capability it cannot go below the value it starts at (nor can any
    other user's Chromium)."""
    increment = max(0, BROWSER_NICE - os.getpriority(os.PRIO_PROCESS, 0))
    command = f"{shlex.quote(path)} " + '"$@"'
    if os.geteuid() == 0:
        command = f"setpriv --bounding-set=-sys_nice --inh-caps=-sys_nice {command}"
    if increment:
        command = f"nice -n {increment} {command}"
    launcher = directory / "chromium"
    launcher.write_text(f"#!/bin/sh\nexec {command}\n")
    launcher.chmod(0o755)
    return str(launcher)


def _check_niced() -> None:
    """Every browser process this test started runs at :data:`BROWSER_NICE` or above
    (Playwright's driver, ``node``, is not the browser)."""
    seen = 0
    for pid in descendants(os.getpid()):
        try:
            if Path(f"/proc/{pid}/comm").read_text().strip() != "chromium":
                continue
            nice = os.getpriority(os.PRIO_PROCESS, pid)
        except OSError:  # ended meanwhile
            continue
        seen += 1
        assert nice >= BROWSER_NICE, f"chromium {pid} runs at nice {nice}"
    assert seen, "no chromium process among this test's"

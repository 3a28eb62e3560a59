"""Debian's chromium, headless, driven by Playwright for Python (never a browser that
Playwright downloads): what the ``browser`` tests use."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

CHROMIUM_ARGS = [
    "--no-sandbox",  # root in CI
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",  # this machine has no network: no lookups at start
    "--disable-component-update",
    "--disable-sync",
]


def chromium_path() -> str | None:
    """The system Chromium (``$ROVER_CHROMIUM``, else ``chromium`` on the PATH)."""
    return os.environ.get("ROVER_CHROMIUM") or shutil.which("chromium")


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Chromium browser (Playwright's ``Browser``); skips, saying why, where
    Chromium or Playwright is missing. Closed (the browser and Playwright's driver
    process ended) on exit."""
    path = chromium_path()
    if path is None:
        pytest.skip("no chromium: apt-get install chromium (bash .ci/bootstrap --test does)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("no playwright for Python: pip install -e '.[test]'")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=path, headless=True, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()

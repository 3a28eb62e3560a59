"""Shared fixtures of the device tooling's tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from udev.verify import CheckUnavailableError, verify_rules

REQUIRE_UDEV_CHECK_ENV = "ROVER_REQUIRE_UDEV_CHECK"
"""With ``1`` (set by .ci/test), a machine where udev cannot check rules fails the tests
that need the check instead of skipping them."""


@pytest.fixture(scope="session")
def udev_check(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Which check udev runs here (``udevadm verify`` or the sandboxed ``udevadm
    test``); skips the test where neither can run, saying why, or fails it under
    ``ROVER_REQUIRE_UDEV_CHECK=1``."""
    probe = Path(tmp_path_factory.mktemp("udev-check"), "50-probe.rules")
    probe.write_text('SUBSYSTEM=="tty", SYMLINK+="probe"\n')
    try:
        return verify_rules([probe]).checker
    except CheckUnavailableError as exc:
        if os.environ.get(REQUIRE_UDEV_CHECK_ENV) == "1":
            raise
        pytest.skip(f"udev cannot check rules here: {exc}")

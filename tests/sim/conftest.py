"""Fixtures of the simulator's tests."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest


@pytest.fixture(autouse=True)
def quiet_parts() -> Iterator[None]:
    """Every fault of a scenario makes the link and the controller log a warning: keep
    them out of the captured logs (thousands of scenarios), as ``rover sim`` does."""
    loggers = [logging.getLogger(name) for name in ("bridge", "emulator")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    yield
    for lg, level in zip(loggers, levels, strict=True):
        lg.setLevel(level)

"""Fixtures of the twin tests: the rover description."""

from __future__ import annotations

import pytest

from firmware_proto.rover import RoverDescription, load_rover


@pytest.fixture(scope="session")
def rover() -> RoverDescription:
    return load_rover()

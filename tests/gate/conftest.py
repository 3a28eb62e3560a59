"""Gate fixtures: the validator, real servers on 127.0.0.1 (threads or processes)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from multiprocessing import resource_tracker
from typing import Any

import pytest

from firmware_proto.model.rover import RoverDescription, load_rover
from gate.config import GateConfig, PlaybackSettings
from gate.pool import WorkerPool
from gate.server import GateServer
from gate.validator import Validator, load_maps


@pytest.fixture(scope="session", autouse=True)
def _resource_tracker() -> None:
    """Process pools use named semaphores, whose cleanup helper is a process that lives
    as long as the test session: start it up front, so that it is not taken for a
    process leaked by the first test that starts a pool."""
    resource_tracker.ensure_running()


@pytest.fixture(scope="session")
def rover() -> RoverDescription:
    return load_rover()


@pytest.fixture(scope="session")
def validator(rover: RoverDescription) -> Validator:
    maps, default = load_maps("lab")
    return Validator(rover, maps, PlaybackSettings(), default)


def thread_config(**overrides: Any) -> GateConfig:
    """A config for in-process tests: a free port, two worker threads."""
    base: dict[str, Any] = {"port": 0, "pool": "thread", "workers": 2}
    return GateConfig(**(base | overrides))


@pytest.fixture(scope="module")
def http_gate() -> Iterator[GateServer]:
    """A thread-pool gate shared by a module's read-only tests."""
    with GateServer(thread_config()) as gate:
        yield gate


@pytest.fixture
def make_gate(
    validator: Validator,
) -> Iterator[Callable[..., GateServer]]:
    """Factory of started gates: a thread pool of two unless ``worker_pool`` (a pool
    object) or ``pool`` (a config kind) say otherwise; config fields as keywords. Every
    gate is closed after the test."""
    started: list[GateServer] = []

    def make(
        *,
        worker_pool: WorkerPool | None = None,
        validator_: Validator | None = None,
        **overrides: Any,
    ) -> GateServer:
        gate = GateServer(
            thread_config(**overrides), validator=validator_ or validator, pool=worker_pool
        ).start()
        started.append(gate)
        return gate

    yield make
    for gate in started:
        gate.close()

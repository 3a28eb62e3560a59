"""Emulator fixtures: the rover, maps, lockstep controllers and served emulators."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator

import pytest

from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.injection import FaultSpec
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap, load_map
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY
from tests.scheduling import threads_at

SPEED = 4.0
"""Twin seconds per wall second in served tests: fast, with timeouts scaled to match."""

_channels = itertools.count()


@pytest.fixture(scope="session")
def rover() -> RoverDescription:
    return load_rover()


@pytest.fixture(scope="session")
def lab() -> WorldMap:
    return load_map("lab")


@pytest.fixture
def make_model(rover: RoverDescription) -> Callable[..., ControllerModel]:
    """Factory of lockstep controllers: open plane by default, seeded."""

    def make(world: WorldMap | None = None, *, seed: int = 1, **config: object) -> ControllerModel:
        return ControllerModel(rover, Twin(rover, world), ControllerConfig(**config), seed=seed)  # type: ignore[arg-type]

    return make


@pytest.fixture
def serial_emulator(rover: RoverDescription) -> Iterator[Callable[..., Emulator]]:
    """Factory of emulators served on a real pty at SPEED x real time; all closed after."""
    started: list[Emulator] = []

    def make(
        world: WorldMap | None = None,
        *,
        seed: int = 1,
        baud: int | None = None,
        faults: list[FaultSpec] | None = None,
    ) -> Emulator:
        model = ControllerModel(
            rover, Twin(rover, world), ControllerConfig(timeout_scale=SPEED), seed=seed
        )
        emu = Emulator(
            model, SerialFrontEnd(baud=baud, seed=seed), speed_factor=SPEED, faults=faults
        )
        with threads_at(EMULATOR_PRIORITY):  # as `rover emulate` runs it
            emu.start()
        started.append(emu)
        return emu

    yield make
    for emu in started:
        emu.close()


@pytest.fixture
def can_channel() -> str:
    """A fresh python-can virtual channel name."""
    return f"emu-test-{next(_channels)}"

"""Planner fixtures: a real gate on 127.0.0.1 (its HTTP server in this process, one
worker thread, or a ``rover gate`` process), clients of it, the planner, maps as the
planner reads them; one ``rover stack up`` at a time in a run."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap, list_maps, load_map
from gate.config import GateConfig
from gate.server import GateServer
from planner.plan.gate_client import GateClient
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner
from planner.stack.domains import registry_dir


def start_gate(**overrides: Any) -> GateServer:
    """A started gate: a free port, one worker thread (warmed up, so that no thread
    starts during a test), the shipped maps."""
    base: dict[str, Any] = {"port": 0, "pool": "thread", "workers": 1, "queue_depth": 4}
    gate = GateServer(GateConfig(**(base | overrides))).start()
    try:
        with GateClient(gate.url, token=overrides.get("token")) as client:
            client.validate(
                {
                    "goal": {"x": 1.2, "y": 3, "yaw_deg": 0},
                    "commands": [{"command": "FWD", "speed": 0, "distance": 0}],
                },
                map_name="lab",
            )
    except BaseException:
        gate.close()
        raise
    return gate


@pytest.fixture(scope="module")
def gate() -> Iterator[GateServer]:
    """A gate shared by a module's tests (they only read from it)."""
    with start_gate() as server:
        yield server


@pytest.fixture(scope="module")
def gate_process_url() -> Iterator[str]:
    """The URL of a ``rover gate`` process (two worker threads) shared by a module's
    tests; terminated after them."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "gate",
            "--port=0",
            "--pool=thread",
            "--workers=2",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line and line[0] == "GATE", proc.stderr.read() if proc.stderr else ""
        yield line[1]
    finally:
        proc.terminate()
        proc.communicate(timeout=15)


@pytest.fixture
def client(gate: GateServer) -> Iterator[GateClient]:
    """A client of the shared gate, closed after the test."""
    with GateClient(gate.url) as c:
        yield c


@pytest.fixture(scope="session")
def rover() -> RoverDescription:
    return load_rover()


@pytest.fixture(scope="session")
def planner(rover: RoverDescription) -> HeuristicLowLevelPlanner:
    return HeuristicLowLevelPlanner(rover)


@pytest.fixture(scope="session")
def worlds() -> dict[str, WorldMap]:
    """The shipped maps, read from their files."""
    return {name: load_map(name) for name in list_maps()}


@pytest.fixture
def orchestrator(
    planner: HeuristicLowLevelPlanner, client: GateClient
) -> Callable[..., PlannerOrchestrator]:
    """Factory of orchestrators on the shared gate."""

    def make(map_name: str, **kwargs: Any) -> PlannerOrchestrator:
        return PlannerOrchestrator(planner, client, map_name=map_name, **kwargs)

    return make


def ring_map(path: Path, center: tuple[float, float], half_side_m: float) -> Path:
    """A 10 x 10 m map file whose goal at ``center`` is walled in on all four sides."""
    cx, cy = center
    h = half_side_m
    corners = [(cx - h, cy - h), (cx + h, cy - h), (cx + h, cy + h), (cx - h, cy + h)]
    walls = [
        {
            "id": f"wall_{i}",
            "type": "segment",
            "a": list(corners[i]),
            "b": list(corners[(i + 1) % 4]),
            "radius": 0.05,
        }
        for i in range(4)
    ]
    doc = {
        "name": "ring",
        "description": "A goal walled in on all sides: unreachable.",
        "bounds": {"min_x": 0.0, "min_y": 0.0, "max_x": 10.0, "max_y": 10.0},
        "obstacles": walls,
        "traction_regions": [],
        "start": {"x": 1.0, "y": 1.0, "yaw_deg": 0.0},
        "goals": [{"name": "inside", "x": cx, "y": cy, "yaw_deg": 0.0}],
    }
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def slot_map(path: Path) -> Path:
    """A 10 x 10 m map whose goal (6, 6, 90 deg) lies in a 0.9 m wide slot open to the
    south: the rover fits lengthwise but cannot turn there."""
    walls = [
        {"id": "west", "type": "segment", "a": [5.5, 5.3], "b": [5.5, 7.2], "radius": 0.05},
        {"id": "east", "type": "segment", "a": [6.5, 5.3], "b": [6.5, 7.2], "radius": 0.05},
        {"id": "back", "type": "segment", "a": [5.5, 7.2], "b": [6.5, 7.2], "radius": 0.05},
    ]
    doc = {
        "name": "slot",
        "description": "A goal in a slot the rover cannot turn in.",
        "bounds": {"min_x": 0.0, "min_y": 0.0, "max_x": 10.0, "max_y": 10.0},
        "obstacles": walls,
        "traction_regions": [],
        "start": {"x": 1.0, "y": 1.0, "yaw_deg": 0.0},
        "goals": [{"name": "in_the_slot", "x": 6.0, "y": 6.0, "yaw_deg": 90.0}],
    }
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


@pytest.fixture
def one_stack() -> Iterator[None]:
    """Hold the run's stack lock for the test: one ``rover stack up`` at a time.

    Stacks and demos claim their ROS domains in the run's one directory
    (tests/conftest.py), so two never share one; but ``rover stack env``, ``rover stack
    inject`` and ``rover status`` without ``--domain`` name *the* stack, and with two
    running they ask which. A test that starts a stack takes this, so that the commands
    it runs as the docs write them find one (waiting up to 600 s for another's)."""
    path = registry_dir() / "tests-one-stack.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        deadline = time.monotonic() + 600.0
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"another test's rover stack held {path} 600 s") from None
                time.sleep(0.1)  # flock has no time limit of its own
        yield
    finally:
        os.close(fd)  # drops the lock

"""Whole missions in virtual time (docs/sim.md, "Whole missions in virtual time"): plan, gate,
executor, relay with its 3 s round trip, bridge, controller (the Python model or the C
core) over serial or CAN, twin; one process, one thread, no wall clock.

Each named mission (:mod:`sim.worldmissions`) is played against both controllers on both
media; a failure prints the one command line that plays it again. What the in-process
rigs checked in real time (tests/planner/test_ground_e2e.py, test_mission.py) is
checked here, and the real-time smoke of the same path stays (tests/planner/test_demo.py).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from gate.server import GateServer
from sim.cli_sim import _world_names
from sim.world import CONTROLLERS, MEDIA, World, WorldConfig
from sim.worldmissions import MISSIONS, WorldOutcome, play, start_gate

ROOT = Path(__file__).resolve().parents[2]

FAST = {("approved", "python", "serial"), ("slip", "c", "can"), ("rejected", "python", "can")}
"""What the fast lane plays; every mission against both controllers on both media runs
in the test command (``virtual``: slow, no wall clock)."""

SLOW = (pytest.mark.slow, pytest.mark.virtual)
CASES = [
    pytest.param(
        mission, controller, medium,
        id=f"{mission}-{controller}-{medium}",
        marks=() if (mission, controller, medium) in FAST else SLOW,
    )
    for mission in MISSIONS
    for controller in CONTROLLERS
    for medium in MEDIA
]  # fmt: skip


@pytest.fixture(scope="module")
def gate() -> Iterator[GateServer]:
    """One gate (a thread pool in this process) for the module's missions."""
    with start_gate() as server:
        yield server


def _check(outcome: WorldOutcome) -> None:
    assert outcome.ok, outcome.report()


@pytest.mark.parametrize(("mission", "controller", "medium"), CASES)
def test_the_mission_goes_as_it_must(
    gate: GateServer, mission: str, controller: str, medium: str
) -> None:
    config = WorldConfig(controller=controller, medium=medium, seed=5)
    outcome = play(mission, config, gate_url=gate.url)
    _check(outcome)
    assert outcome.sim_s > 1.0  # it ran in virtual time, not nowhere


def test_a_world_plays_the_same_from_its_seed_and_differs_with_it(gate: GateServer) -> None:
    first = play("rejected", WorldConfig(seed=3), gate_url=gate.url)
    again = play("rejected", WorldConfig(seed=3), gate_url=gate.url)
    other = play("rejected", WorldConfig(seed=4), gate_url=gate.url)
    _check(first)
    assert first.digest == again.digest
    assert first.digest != other.digest  # sensor noise and the boot nonce follow the seed


@pytest.mark.slow  # another process: out of the fast lane, no wall clock
@pytest.mark.virtual
def test_a_failure_prints_the_command_that_plays_it_again() -> None:
    """A lossy link loses the plan's statuses: the mission fails, and says how to play it
    again; that command fails the same way, in another process, with the same digest."""
    config = WorldConfig(seed=2, loss=0.9, rtt_s=1.0)
    outcome = play("approved", config)
    assert not outcome.ok
    line = outcome.report().splitlines()[0]
    assert line.startswith("FAIL rover sim --world approved --seed 2 ")
    assert "--loss 0.9" in line and "--rtt 1" in line
    args = outcome.reproducer.split()[2:]
    env = {**os.environ, "PYTHONHASHSEED": "7"}  # another process, other hashes
    done = subprocess.run(
        [sys.executable, "-m", "sim.cli_sim", *args],
        capture_output=True, text=True, cwd=ROOT, timeout=100, env=env, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stdout.startswith(f"FAIL {outcome.reproducer}  (")
    for failed in outcome.failed:
        assert f"failed: {failed}" in done.stdout


def test_the_clis_mission_names_are_the_missions() -> None:
    assert _world_names() == list(MISSIONS)


def test_a_world_starts_no_thread_and_leaves_nothing_behind() -> None:
    before = set(threading.enumerate())
    with World(WorldConfig(seed=1)) as world:
        assert set(threading.enumerate()) == before
        assert world.bridge.link.ready
        world.run_for(2.0)
        assert world.executor.pose_source_in_use == "odom_ground"
    assert set(threading.enumerate()) == before

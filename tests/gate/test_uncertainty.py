"""Verdicts with their uncertainty (docs/gate.md): the twins in one batch agree with the
single twin, the draws are seeded, the summary is what its samples say, bad options are
400s, and a real local Dask cluster (a scheduler and two workers, each its own process,
on loopback) answers the same bytes as the gate's own process pool."""

from __future__ import annotations

import contextlib
import math
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest

from emulator.batch import BatchDraw, play_batch, schedule
from emulator.ground import Ground
from emulator.playback import play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.plan import Plan
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import load_map
from gate.config import GateConfig, PlaybackSettings
from gate.ensemble import DefaultSpread, chunk_sizes
from gate.openapi import build_openapi
from gate.options import ValidateOptions
from gate.server import GateServer
from gate.validator import Validator, load_maps
from tests.child import Child
from tests.gate.client import call, post_plan

QUARTER = 15484
SQUARE = {
    "goal": {"x": 1.0, "y": 4.0, "yaw_deg": 0.0},
    "commands": [
        {"command": c, "speed": s, "distance": d}
        for c, s, d in [("FWD", 60, 28750), ("FWD", 60, 28750), ("LEFT", 30, QUARTER)] * 4
    ],
}
"""bench_gate's 12-step plan: four sides of 2 x 1.25 m on scn01, through its region."""
SHORT = {
    "goal": {"x": 3.1, "y": 3.0, "yaw_deg": 0.0},
    "commands": [
        {"command": "FWD", "speed": 40, "distance": 30000},
        {"command": "FWD", "speed": 40, "distance": 13700},
    ],
}
"""1.9 m toward the lab's table: the nominal twin stops 5 cm short of touching it (at
the 0.1 m margin)."""


@pytest.fixture(scope="module")
def rover() -> RoverDescription:
    return load_rover()


def test_a_batch_twin_plays_as_the_single_twin(rover: RoverDescription, kernel: str) -> None:
    world = load_map("scn01")
    plan = Plan.from_dict(SQUARE)
    start = Pose2D.from_deg(1.0, 4.0, 0.0)
    single = play(Twin(rover, world, dt_s=0.01, safety_margin_m=0.1, start=start), plan.to_wire())
    nominal = BatchDraw(Ground.of_rover(rover, world))
    batch = play_batch(
        rover, world, [nominal] * 3, plan.to_wire(),
        dt_s=0.01, safety_margin_m=0.1, start=start, record_every_s=1.0, kernel=kernel,
    )  # fmt: skip
    assert [(round(s.start_time_s / 0.01), round(s.end_time_s / 0.01)) for s in single.steps] == (
        list(batch.schedule.step_ticks)
    )
    f = single.final_pose
    for x, y, yaw in batch.final:
        assert math.hypot(x - f.x_m, y - f.y_m) < 1e-7 and abs(yaw - f.yaw_rad) < 1e-7
    assert (batch.collision_tick == -1).all()
    for step, (_, end) in zip(single.steps, batch.schedule.step_ticks, strict=True):
        row = batch.record_ticks.index(end)
        x, y, _ = batch.poses[row, 0]
        assert math.hypot(x - step.end_pose.x_m, y - step.end_pose.y_m) < 1e-7


def test_a_batch_twin_collides_where_the_single_twin_does(
    rover: RoverDescription, kernel: str
) -> None:
    world = load_map("lab")
    steps = [(1, 60, 30000), (1, 60, 30000)]  # straight into the table
    single = play(Twin(rover, world, dt_s=0.01, safety_margin_m=0.1), steps)
    draws = [BatchDraw(Ground.of_rover(rover, world))]
    start = Pose2D.from_deg(world.start.x, world.start.y, world.start.yaw_deg)
    batch = play_batch(
        rover, world, draws * 2, steps, dt_s=0.01, safety_margin_m=0.1, start=start,
        record_every_s=1.0, kernel=kernel,
    )  # fmt: skip
    assert single.collision is not None
    assert batch.collision_obstacle == (single.collision.obstacle_id,) * 2
    assert list(batch.collision_tick) == [round(single.collision.time_s / 0.01)] * 2
    assert batch.collision_contact[0, 0] == pytest.approx(single.collision.contact_x_m, abs=1e-7)


def test_the_schedule_is_the_playbacks(rover: RoverDescription) -> None:
    plan = schedule(rover, Plan.from_dict(SQUARE).to_wire(), 0.01)
    assert plan.completed == (True,) * 12 and plan.stall is None
    assert plan.ticks == plan.step_ticks[-1][1] == 5500


def test_chunks_depend_on_n_alone() -> None:
    assert chunk_sizes(1) == [1]
    assert chunk_sizes(3) == [2, 1]
    assert chunk_sizes(200) == [100, 100]
    assert chunk_sizes(1001) == [91] + [91] * 10
    assert sum(chunk_sizes(997)) == 997


def test_default_spread_is_seeded_and_spread(rover: RoverDescription) -> None:
    spread = DefaultSpread(Ground.of_rover(rover))
    a, b = spread.sample(7, 50), spread.sample(7, 50)
    assert a == b and a != spread.sample(8, 50)
    logs = np.log([g.mu_lateral / rover.traction.mu_lateral for g in a])
    assert 0.1 < logs.std() < 0.3


@pytest.fixture(scope="module")
def validator(rover: RoverDescription) -> Validator:
    maps, default = load_maps("lab")
    return Validator(rover, maps, PlaybackSettings(), default)


def uncertain(validator: Validator, plan: dict[str, Any], query: str) -> Verdict:
    options = ValidateOptions.from_query(query).resolve(validator.settings, "lab")
    return validator.validate_uncertain(validator.prepare(Plan.from_dict(plan), options))


def test_the_summary_says_what_the_samples_did(validator: Validator) -> None:
    v = uncertain(validator, SHORT, "samples=40&seed=3&slip_sigma=0.1")
    u = v.uncertainty
    assert u is not None and u.samples == 40 and u.seed == 3 and u.spread == "default"
    assert v.replay.seed == 3 and "samples=40&seed=3&slip_sigma=0.1" in v.replay.query
    hits = sum(h.count for h in u.collisions)
    assert u.collision_probability == pytest.approx(hits / 40)
    assert u.goal_error.samples == 40 - hits
    lo, mid, hi = u.goal_error.distance_m
    assert 0.0 <= lo <= mid <= hi
    # The envelope: one point per second of the step and its end, widening as it goes.
    assert [p.step for p in u.envelope] == sorted(p.step for p in u.envelope)
    assert {p.step for p in u.envelope} == {0, 1}
    assert u.envelope[-1].step_t_s == pytest.approx(v.steps[1].expected_duration_s, abs=1e-6)
    assert u.envelope[-1].major_m > u.envelope[0].major_m > 0.0
    assert all(p.major_m >= p.minor_m >= 0.0 for p in u.envelope)
    end = u.envelope[-1].pose
    assert math.hypot(end.x - v.final_pose.x, end.y - v.final_pose.y) < 0.3
    again = uncertain(validator, SHORT, "samples=40&seed=3&slip_sigma=0.1")
    assert again.uncertainty == u
    other = uncertain(validator, SHORT, "samples=40&seed=4&slip_sigma=0.1")
    assert other.uncertainty != u


def test_no_spread_gives_no_spread(validator: Validator) -> None:
    narrow = Validator(
        validator.rover,
        validator.maps,
        validator.settings,
        "lab",
        spread=DefaultSpread(Ground.of_rover(validator.rover), sigma=0.0),
    )
    v = uncertain(narrow, SHORT, "samples=4&slip_sigma=0")
    u = v.uncertainty
    assert u is not None and u.collision_probability == 0.0
    assert u.goal_error.distance_m == (v.distance_error_m,) * 3
    assert all(p.major_m == 0.0 for p in u.envelope)


@pytest.fixture(scope="module")
def gate() -> Iterator[GateServer]:
    with GateServer(GateConfig(port=0, pool="process", workers=2)) as server:
        yield server


def test_the_gate_answers_with_the_documented_uncertainty(gate: GateServer) -> None:
    single = post_plan(gate.address, SHORT, "map=lab")
    assert single.status == 200 and "uncertainty" not in single.json()
    r = post_plan(gate.address, SHORT, "map=lab&samples=30&seed=5")
    assert r.status == 200, r.body[:300]
    doc = build_openapi(gate.config, sorted(gate.validator.maps), "lab")
    schema = {"$ref": "#/components/schemas/Verdict", "components": doc["components"]}
    jsonschema.validate(r.json(), schema)
    assert r.json()["uncertainty"]["samples"] == 30
    assert (
        post_plan(gate.address, SHORT, "map=lab&samples=30&seed=5").without_wall_time()
        == r.without_wall_time()
    )


@pytest.mark.parametrize(
    ("query", "parameter"),
    [
        ("samples=0", "samples"),
        ("samples=2001", "samples"),
        ("samples=1.5", "samples"),
        ("samples=-3", "samples"),
        ("seed=99999999999", "seed"),
        ("slip_sigma=2", "slip_sigma"),
        ("slip_sigma=nan", "slip_sigma"),
        ("start_sigma_m=-0.001", "start_sigma_m"),
        ("start_sigma_deg=90", "start_sigma_deg"),
    ],
)
def test_bad_sample_options_are_400s(gate: GateServer, query: str, parameter: str) -> None:
    before = gate.rejected["invalid_option"]
    r = post_plan(gate.address, SHORT, f"map=lab&{query}")
    assert r.status == 400 and r.json()["parameter"] == parameter
    assert gate.rejected["invalid_option"] == before + 1


# -- a real local Dask cluster -----------------------------------------------------------


def _documented_cluster_commands() -> list[list[str]]:
    """The command lines of docs/gate.md's "A Dask cluster", as argument lists."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "gate.md").read_text()
    section = text.split("### A Dask cluster", 1)[1]
    block = re.findall(r"```\n(.*?)```", section, flags=re.S)[0]
    return [shlex.split(line) for line in block.splitlines() if line.strip()]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[str]]:
    """docs/gate.md's cluster, started as written: the scheduler and the worker's line
    twice (one per core), each a process of its own on 127.0.0.1, with a free port for
    Dask's 8786; yields the gate's command line (its port still to fill in)."""
    pytest.importorskip("distributed")
    scheduler, worker, gate = _documented_cluster_commands()
    assert scheduler[:2] == [".venv/bin/dask", "scheduler"] and worker[:2] == [
        ".venv/bin/dask",
        "worker",
    ], "docs/gate.md's cluster commands changed: change this test with them"
    assert gate[:2] == [".venv/bin/rover", "gate"]
    port = str(_free_port())
    venv_bin = str(Path(sys.executable).parent)

    def local(command: list[str]) -> list[str]:
        out = [arg.replace("8786", port) for arg in command]
        return [out[0].replace(".venv/bin", venv_bin), *out[1:]]

    log = (tmp_path_factory.mktemp("dask") / "cluster.log").open("wb")
    procs: list[subprocess.Popen[bytes]] = []
    try:
        for command in (scheduler, worker, worker):
            procs.append(
                subprocess.Popen(local(command), stdout=log, stderr=log, start_new_session=True)
            )
        from distributed import Client

        with Client(f"tcp://127.0.0.1:{port}", timeout="60s", set_as_default=False) as client:
            client.wait_for_workers(2, timeout=60)
        yield local(gate)
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)
        log.close()


@pytest.mark.slow
def test_the_documented_cluster_answers_the_same_verdict_as_the_local_pool(
    gate: GateServer, cluster: list[str]
) -> None:
    query = "map=scn01&start=1,4,0&samples=200&seed=11"
    local = post_plan(gate.address, SQUARE, query)
    assert local.status == 200, local.body[:300]
    command = [arg.replace("8080", "0") for arg in cluster]
    address = command[command.index("--cluster") + 1]
    on_cluster = Child(command[1:], dict(os.environ))  # rover gate ..., a process
    try:
        url = on_cluster.wait_for("GATE ").split()[1]
        host, port = url.removeprefix("http://").rsplit(":", 1)
        assert call((host, int(port)), "GET", "/health").json()["cluster"] == address
        remote = post_plan((host, int(port)), SQUARE, query)
    finally:
        on_cluster.stop()
    assert remote.status == 200, remote.body[:300]
    assert remote.without_wall_time() == local.without_wall_time()
    u = local.json()["uncertainty"]
    assert u["samples"] == 200 and 0.0 < u["collision_probability"] < 1.0

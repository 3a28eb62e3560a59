"""The gate client against a real gate on 127.0.0.1: verdicts, errors, retries."""

from __future__ import annotations

import math
import select
import socket
from collections.abc import Iterator

import pytest

from firmware_proto.errors import VerdictError
from firmware_proto.model.plan import Goal, Plan, PlanStep
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import Verdict
from gate.server import GateServer
from planner.errors import (
    GateOverloadedError,
    GateProtocolError,
    GateStatusError,
    GateTimeoutError,
    GateUnavailableError,
    PlannerError,
)
from planner.plan.gate_client import GateClient, GateOptions, resolve_gate_settings
from planner.plan.planner import HeuristicLowLevelPlanner
from tests.planner.conftest import start_gate


def open_field_plan(planner: HeuristicLowLevelPlanner) -> Plan:
    """Two metres ahead and a quarter turn, on scn01 from its start (nothing there)."""
    return planner.plan(Pose(1.0, 4.0, 0.0), Pose(3.0, 4.0, 90.0))


@pytest.fixture
def free_port() -> int:
    """A port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


@pytest.fixture
def own_gate() -> Iterator[GateServer]:
    """A gate of the test's own, for tests that change its state."""
    with start_gate() as server:
        yield server


def test_open_field_plan_is_approved_with_its_trajectory(
    client: GateClient, planner: HeuristicLowLevelPlanner
) -> None:
    plan = open_field_plan(planner)
    verdict = client.validate(plan, map_name="scn01", start=Pose(1.0, 4.0, 0.0))
    assert verdict.approved
    assert verdict.failure_type is None
    assert verdict.failed_step is None
    assert verdict.distance_error_m < verdict.tolerances.position_m
    assert math.dist(verdict.final_pose.xy, (3.0, 4.0)) < 0.1
    assert verdict.replay.map == "scn01"
    assert "start=1.0,4.0,0.0" in verdict.replay.query
    # Per step: the plan's steps, their end poses and expected durations.
    assert [(s.command, s.speed, s.distance) for s in verdict.steps] == [
        (c.command, c.speed, c.distance) for c in plan.commands
    ]
    assert all(s.completed and s.expected_duration_s > 0 for s in verdict.steps)
    assert verdict.steps[-1].end_pose.yaw_deg == pytest.approx(90.0, abs=3.0)
    assert verdict.expected_duration_s == pytest.approx(
        sum(s.expected_duration_s for s in verdict.steps)
    )
    # The trajectory is tagged with the step and the time into it.
    samples = verdict.trajectory.samples
    assert {s.step for s in samples} == set(range(len(plan.commands)))
    for step in range(len(plan.commands)):
        mine = verdict.trajectory.for_step(step)
        assert mine[0].step_t_s == 0.0
        assert [s.step_t_s for s in mine] == sorted(s.step_t_s for s in mine)
    assert [s.t_s for s in samples] == sorted(s.t_s for s in samples)
    first = verdict.trajectory.for_step(0)
    halfway = verdict.trajectory.pose_at(0, first[-1].step_t_s / 2)
    assert halfway is not None
    assert first[0].pose.x < halfway.x < first[-1].pose.x
    assert verdict.trajectory.pose_at(99, 0.0) is None


def test_keep_alive_and_reads(client: GateClient, planner: HeuristicLowLevelPlanner) -> None:
    plan = open_field_plan(planner)
    client.validate(plan, map_name="scn01")
    conn = client._conn
    client.validate(plan, map_name="scn01")
    assert client._conn is conn  # one connection for both
    health = client.health()
    assert health["status"] == "ok"
    default, maps = client.list_maps()
    assert default == "lab"
    assert {m["name"] for m in maps} >= {"lab", "scn01", "scn02", "scn03"}
    world = client.get_map("scn03")
    assert world.name == "scn03"
    assert len(world.obstacles) == 19
    assert client.get_map().name == "lab"
    assert client.requests == 7  # get_map() asks for the default first


def test_options_reach_the_gate(client: GateClient, planner: HeuristicLowLevelPlanner) -> None:
    options = GateOptions(margin_m=0.2, pos_tol_m=0.05, yaw_tol_deg=1.5, sample_hz=20.0)
    verdict = client.validate(open_field_plan(planner), map_name="scn01", options=options)
    assert verdict.tolerances.safety_margin_m == 0.2
    assert verdict.tolerances.position_m == 0.05
    assert verdict.tolerances.yaw_deg == 1.5
    assert verdict.trajectory.sample_period_s == pytest.approx(0.05)
    measured = GateOptions(samples=4, start_sigma_m=0.001, start_sigma_deg=0.05)
    assert ("start_sigma_m", "0.001") in measured.query_items()
    uncertain = client.validate(open_field_plan(planner), map_name="scn01", options=measured)
    assert uncertain.uncertainty is not None and uncertain.uncertainty.samples == 4


def test_schema_violations_give_gate_error_with_pointers(client: GateClient) -> None:
    bad = {
        "goal": {"x": 1, "y": 2, "yaw_deg": 0},
        "commands": [
            {"command": "FWD", "speed": 61, "distance": 100},
            {"command": "JUMP", "speed": 1, "distance": 1},
        ],
        "extra": True,
    }
    with pytest.raises(GateStatusError) as err:
        client.validate(bad)
    e = err.value
    assert e.status == 400
    assert e.code == "plan_schema"
    assert set(e.pointers) == {"/commands/0/speed", "/commands/1/command", "/extra"}
    assert "/commands/0/speed" in str(e)
    assert isinstance(e, PlannerError)
    assert client.requests == 1  # a 4xx is never retried


def test_bad_options_name_the_parameter(
    client: GateClient, planner: HeuristicLowLevelPlanner
) -> None:
    plan = open_field_plan(planner)
    with pytest.raises(GateStatusError) as err:
        client.validate(plan, map_name="mars")
    assert (err.value.status, err.value.parameter) == (400, "map")
    with pytest.raises(GateStatusError) as err:
        client.validate(plan, map_name="lab", start=Pose(50.0, 1.0, 0.0))
    assert (err.value.status, err.value.parameter) == (400, "start")
    assert "outside map 'lab'" in err.value.message
    with pytest.raises(GateStatusError) as err:
        client.get_map("mars")
    assert err.value.status == 404
    with pytest.raises(ValueError, match="finite"):
        client.validate(plan, start=Pose(math.nan, 1.0, 0.0))


def test_gate_down_gives_unavailable_after_limited_retries(free_port: int) -> None:
    waits: list[float] = []
    url = f"http://127.0.0.1:{free_port}"
    with (
        GateClient(url, retries=3, backoff_s=0.1, sleep=waits.append) as client,
        pytest.raises(GateUnavailableError) as err,
    ):
        client.validate({"goal": {"x": 0, "y": 0, "yaw_deg": 0}, "commands": []})
    assert err.value.attempts == 4
    assert waits == [0.1, 0.2, 0.4]
    assert err.value.url == url
    assert url in str(err.value)
    assert "Connection refused" in str(err.value) or "ConnectionRefusedError" in str(err.value)
    assert isinstance(err.value, ConnectionError)


def test_backoff_is_capped_and_stays_within_the_budget(free_port: int) -> None:
    waits: list[float] = []
    url = f"http://127.0.0.1:{free_port}"
    with (
        GateClient(url, retries=6, backoff_s=0.5, max_backoff_s=1.0, sleep=waits.append) as c,
        pytest.raises(GateUnavailableError),
    ):
        c.health()
    assert waits == [0.5, 1.0, 1.0, 1.0, 1.0, 1.0]


def test_silent_gate_times_out() -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:  # accepts, never answers
        url = f"http://127.0.0.1:{listener.getsockname()[1]}"
        with GateClient(url, timeout_s=0.3) as client, pytest.raises(GateTimeoutError) as err:
            client.health()
    assert err.value.timeout_s == 0.3
    assert isinstance(err.value, TimeoutError)
    assert isinstance(err.value, GateUnavailableError)


def test_overloaded_gate_is_retried_after_retry_after_then_reported(own_gate: GateServer) -> None:
    own_gate.begin_drain()  # from now on: 503 with Retry-After: 1
    with GateClient(own_gate.url, timeout_s=0.5) as client:
        with pytest.raises(GateOverloadedError) as err:
            client.health()
        assert client.requests == 1  # Retry-After is beyond the budget: no retry
    assert err.value.status == 503
    assert err.value.retry_after_s == 1.0
    assert err.value.code == "shutting_down"
    # With room in the budget the client waits as told, then tries again (a fake
    # clock that the waits advance: no real waiting).
    now = [0.0]
    waits: list[float] = []

    def sleep(seconds: float) -> None:
        waits.append(seconds)
        now[0] += seconds

    with GateClient(own_gate.url, timeout_s=2.5, sleep=sleep, clock=lambda: now[0]) as client:
        with pytest.raises(GateOverloadedError):
            client.health()
        assert client.requests == 3
    assert waits == [1.0, 1.0]


def test_bearer_token(planner: HeuristicLowLevelPlanner) -> None:
    with start_gate(token="s3cret") as gate:
        with GateClient(gate.url) as anonymous, pytest.raises(GateStatusError) as err:
            anonymous.health()
        assert err.value.status == 401
        with GateClient(gate.url, token="s3cret") as client:
            assert client.validate(open_field_plan(planner), map_name="scn01").approved
        env = {"ROVER_GATE_URL": gate.url, "ROVER_GATE_TOKEN": "s3cret"}
        with GateClient(environ=env) as from_env:
            assert from_env.health()["status"] == "ok"


def test_a_keep_alive_connection_the_gate_closed_is_reopened(
    planner: HeuristicLowLevelPlanner,
) -> None:
    with start_gate(idle_timeout_s=0.2) as gate, GateClient(gate.url) as client:
        client.health()
        sock = client._conn.sock if client._conn is not None else None
        assert sock is not None
        readable, _, _ = select.select([sock], [], [], 10.0)  # the gate hangs up
        assert readable
        assert client.health()["status"] == "ok"
        assert client.requests == 2


def test_settings_precedence() -> None:
    env = {"ROVER_GATE_URL": "http://127.0.0.1:9", "ROVER_GATE_TOKEN": "t"}
    assert resolve_gate_settings(environ={}) == ("http://127.0.0.1:8080", None)
    assert resolve_gate_settings(environ=env) == ("http://127.0.0.1:9", "t")
    assert resolve_gate_settings("http://127.0.0.1:7", "u", env) == ("http://127.0.0.1:7", "u")
    for bad in ("https://127.0.0.1", "127.0.0.1:80", "http://127.0.0.1/?x=1"):
        with pytest.raises(ValueError, match="gate URL"):
            GateClient(bad)
    with pytest.raises(ValueError, match="timeout_s"):
        GateClient("http://127.0.0.1:1", timeout_s=0)
    client = GateClient("http://127.0.0.1:1")
    client.close()
    client.close()
    with pytest.raises(RuntimeError, match="closed"):
        client.health()


def test_verdict_parsing(gate: GateServer, rover: RoverDescription) -> None:
    from gate.options import ValidateOptions

    plan = Plan(Goal(2.2, 3.0, 0.0), (PlanStep("FWD", 60, 23000),))
    options = ValidateOptions(map="lab").resolve(gate.validator.settings, "lab")
    data = gate.validator.validate(plan, options).to_dict()
    verdict = Verdict.from_dict(data)
    assert verdict.approved
    assert verdict.final_pose.x == pytest.approx(data["final_pose"]["x"])
    assert len(verdict.trajectory.samples) == len(data["trajectory"]["samples"])
    assert verdict.steps[0].left_travel_units == pytest.approx(23000, abs=1)
    data["future_field"] = {"ignored": True}
    assert Verdict.from_dict(data) == verdict
    broken = dict(data)
    del broken["final_pose"]
    with pytest.raises(VerdictError) as err:
        Verdict.from_dict(broken)
    assert err.value.pointers == ("/final_pose",)
    wrong = dict(data, steps=[dict(data["steps"][0], speed="fast")])
    with pytest.raises(VerdictError) as err:
        Verdict.from_dict(wrong)
    assert err.value.pointers == ("/steps/0/speed",)
    with pytest.raises(VerdictError):
        Verdict.from_dict([1, 2])


def test_server_error_is_reported_not_retried(planner: HeuristicLowLevelPlanner) -> None:
    """A gate whose twin breaks (the validator's fault-injection hook) answers 500."""
    from emulator.twin import Twin
    from gate.config import GateConfig, PlaybackSettings
    from gate.validator import Job, Validator, load_maps

    class BrokenValidator(Validator):
        def _make_twin(self, job: Job) -> Twin:
            raise RuntimeError("twin on fire")

    maps, default = load_maps("lab")
    validator = BrokenValidator(load_rover(), maps, PlaybackSettings(), default)
    config = GateConfig(port=0, pool="thread", workers=1)
    with GateServer(config, validator=validator) as gate, GateClient(gate.url) as client:
        with pytest.raises(GateStatusError) as err:
            client.validate(open_field_plan(planner), map_name="lab")
        assert client.requests == 1
    assert err.value.status == 500
    assert err.value.code == "internal_error"


def test_the_planner_reads_the_gates_verdict_into_the_model_the_gate_built(
    client: GateClient, planner: HeuristicLowLevelPlanner
) -> None:
    """The planner reads verdicts over HTTP and may not import the gate: both use the one
    model of firmware_proto.model.verdict, so what the gate serialised reads back equal."""
    import gate
    from firmware_proto.model import verdict as model

    assert gate.Verdict is model.Verdict and gate.FAILURE_TYPES is model.FAILURE_TYPES
    verdict = client.validate(open_field_plan(planner), map_name="lab")
    again = model.Verdict.from_json(verdict.to_json())
    assert again == verdict
    assert verdict.trajectory.samples[-1].pose == verdict.final_pose


def test_a_map_that_is_not_a_map_names_its_bad_field() -> None:
    """The map the gate serves is read with the one map model, its violations becoming
    the pointers of a GateProtocolError."""
    import json
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    bad = {
        "name": "odd",
        "description": "a circle without a centre",
        "bounds": {"min_x": 0, "min_y": 0, "max_x": 5, "max_y": 5},
        "obstacles": [{"id": "a", "type": "circle", "center": [2], "radius": 0.5}],
        "traction_regions": [],
        "start": {"x": 1, "y": 1, "yaw_deg": 0},
    }

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = json.dumps(bad).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: object) -> None:
            pass

    with HTTPServer(("127.0.0.1", 0), Handler) as server:
        thread = threading.Thread(target=server.serve_forever, name="bad-map-gate")
        thread.start()
        try:
            url = f"http://127.0.0.1:{server.server_address[1]}"
            with GateClient(url) as client, pytest.raises(GateProtocolError) as err:
                client.get_map("odd")
        finally:
            server.shutdown()
            thread.join(timeout=10)
    assert err.value.pointers == ("/obstacles/0/center",)
    assert "/maps/odd" in str(err.value)

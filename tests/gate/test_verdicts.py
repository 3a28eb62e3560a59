"""Verdicts over real HTTP: approved, collision, undershoot/overshoot, yaw, start poses."""

from __future__ import annotations

import itertools
import math

import pytest

from emulator.playback import play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import load_map
from gate.render import LEGEND_PX
from gate.server import GateServer

from .client import post_plan
from .plans import fwd, plan, step, turn

LAB_START = (1.2, 3.0, 0.0)


def _verdict(gate: GateServer, body: object, query: str = "") -> Verdict:
    reply = post_plan(gate.address, body, query)
    assert reply.status == 200, reply.body
    assert reply.headers["content-type"] == "application/json"
    return Verdict.from_dict(reply.json())


def test_open_field_plan_is_approved_with_the_twins_final_pose(
    http_gate: GateServer, rover: RoverDescription
) -> None:
    commands = [turn(rover, 30), fwd(1.0), turn(rover, -30)]
    goal = (1.2 + math.cos(math.radians(30)), 3.0 + math.sin(math.radians(30)), 0.0)
    v = _verdict(http_gate, plan(goal, *commands), "map=lab")
    assert v.approved
    assert v.failure_type is None and v.failed_step is None and v.failure_reason == ""
    assert v.collision is None and v.stall is None
    # The predicted final pose is the twin's, at the gate's step and margin.
    twin = Twin(rover, load_map("lab"), dt_s=0.01, safety_margin_m=0.1)
    wire = [
        (3, c["speed"], c["distance"])
        if c["command"] == "LEFT"
        else (4, c["speed"], c["distance"])
        if c["command"] == "RIGHT"
        else (1, c["speed"], c["distance"])
        for c in commands
    ]
    expected = play(twin, wire).final_pose
    assert v.final_pose.x == pytest.approx(expected.x_m, abs=1e-6)
    assert v.final_pose.y == pytest.approx(expected.y_m, abs=1e-6)
    assert v.final_pose.yaw_deg == pytest.approx(expected.yaw_deg, abs=1e-6)
    assert v.distance_error_m < v.tolerances.position_m
    assert abs(v.yaw_error_deg) < v.tolerances.yaw_deg
    assert [s.command for s in v.steps] == ["LEFT", "FWD", "RIGHT"]
    assert all(s.completed for s in v.steps)
    assert v.steps[-1].end_pose == v.final_pose or v.sim_time_s > v.steps[-1].end_time_s


def test_plan_into_an_obstacle_is_a_collision_at_the_right_step(http_gate: GateServer) -> None:
    # Straight at the table: 1.95 m of travel before the 0.1 m margin touches it at
    # x = 3.6, i.e. during the second 1.3 m step.
    body = plan((6.2, 3.0, 0.0), *(step("FWD", 60, 30000) for _ in range(4)))
    v = _verdict(http_gate, body)
    assert not v.approved
    assert v.failure_type == "collision"
    assert v.failed_step == 1
    assert v.collision is not None
    assert v.collision.obstacle_id == "table"
    assert v.collision.step == 1
    assert v.collision.contact.x == pytest.approx(3.6, abs=1e-6)
    assert 2.2 <= v.collision.contact.y <= 3.8
    # The inflated front (0.35 + 0.1 m ahead of the centre) is at the table's face.
    assert v.collision.pose.x + 0.35 + 0.1 == pytest.approx(3.6, abs=0.004)
    assert v.final_pose == v.collision.pose
    assert v.collision.step_t_s == pytest.approx(
        v.collision.time_s - v.steps[1].start_time_s, abs=1e-6
    )
    assert len(v.steps) == 2 and not v.steps[1].completed
    assert "table" in v.failure_reason


def test_collision_with_the_walls_is_reported_as_bounds(
    http_gate: GateServer, rover: RoverDescription
) -> None:
    body = plan((1.2, 5.0, 90.0), turn(rover, 90), step("FWD", 60, 30000), step("FWD", 60, 30000))
    v = _verdict(http_gate, body)
    assert v.failure_type == "collision"
    assert v.collision is not None and v.collision.obstacle_id == "bounds"
    assert v.collision.contact.y == pytest.approx(6.0, abs=1e-6)
    assert v.failed_step == 2


def test_collision_on_a_scenario_map(http_gate: GateServer) -> None:
    # scn02 "behind_rock": straight ahead runs into rock_1 (centre 4.0, 4.2; r 0.45).
    body = plan((7.0, 4.2, 0.0), *(step("FWD", 40, 30000) for _ in range(5)))
    v = _verdict(http_gate, body, "map=scn02")
    assert v.failure_type == "collision"
    assert v.collision is not None and v.collision.obstacle_id == "rock_1"
    assert v.replay.map == "scn02"


def test_undershoot_gives_a_positive_longitudinal_error(http_gate: GateServer) -> None:
    v = _verdict(http_gate, plan((3.2, 3.0, 0.0), fwd(1.0)))
    assert v.failure_type == "goal_not_reached"
    assert v.failed_step == 0
    assert v.position_error_m == pytest.approx(1.0, abs=0.02)  # slip: a few mm short
    assert v.position_error_m > 1.0  # short of 1 m of wheel travel, never past it
    assert v.lateral_error_m == pytest.approx(0.0, abs=1e-6)
    assert v.distance_error_m == pytest.approx(v.position_error_m, abs=1e-6)
    assert v.approach_heading_deg == pytest.approx(0.0, abs=1e-6)
    assert "short of" in v.failure_reason


def test_overshoot_gives_a_negative_longitudinal_error(http_gate: GateServer) -> None:
    v = _verdict(http_gate, plan((1.7, 3.0, 0.0), fwd(1.0)))
    assert v.failure_type == "goal_not_reached"
    assert v.position_error_m == pytest.approx(-0.5, abs=0.02)
    assert "past" in v.failure_reason


def test_errors_are_measured_along_the_approach_not_the_final_heading(
    http_gate: GateServer, rover: RoverDescription
) -> None:
    # Drive north 1 m, then turn to face east: the approach heading is north (90 deg),
    # so a goal 0.5 m further north is an undershoot of 0.5 m, and a goal 0.3 m to the
    # west is on the left.
    body = plan(
        (2.0 - 0.3, 2.0 + 1.5, 0.0),
        turn(rover, 90),
        fwd(1.0),
        turn(rover, -90),
    )
    v = _verdict(http_gate, body, "start=2.0,2.0,0")
    assert v.failure_type == "goal_not_reached"
    assert v.approach_heading_deg == pytest.approx(90.0, abs=2.0)
    assert v.position_error_m == pytest.approx(0.5, abs=0.05)
    assert v.lateral_error_m == pytest.approx(0.3, abs=0.05)


def test_rev_approach_reverses_the_heading(http_gate: GateServer) -> None:
    # Backing 1 m toward a goal 1.5 m behind: still short of it, so positive.
    v = _verdict(http_gate, plan((1.5, 3.0, 0.0), step("REV", 40, 23000)), "start=3.0,3.0,0")
    assert v.approach_heading_deg == pytest.approx(-180.0, abs=1e-6)
    assert v.position_error_m == pytest.approx(0.5, abs=0.02)


def test_turn_short_of_the_goal_yaw_is_yaw_not_reached(
    http_gate: GateServer, rover: RoverDescription
) -> None:
    v = _verdict(http_gate, plan((1.2, 3.0, 90.0), turn(rover, 60)))
    assert v.failure_type == "yaw_not_reached"
    assert v.failed_step == 0
    assert v.yaw_error_deg == pytest.approx(30.0, abs=2.0)  # positive: turn further left
    assert v.distance_error_m < v.tolerances.position_m


def test_yaw_error_is_wrapped(http_gate: GateServer, rover: RoverDescription) -> None:
    # Goal yaw -170 deg; turning left by 170 deg ends near +170: 20 deg short, not 340.
    v = _verdict(http_gate, plan((1.2, 3.0, -170.0), turn(rover, 170)))
    assert v.failure_type == "yaw_not_reached"
    assert -180.0 <= v.yaw_error_deg < 180.0
    assert abs(v.yaw_error_deg) == pytest.approx(20.0, abs=3.0)


def test_tolerances_come_from_the_query(http_gate: GateServer) -> None:
    body = plan((3.2, 3.0, 0.0), fwd(1.0))
    v = _verdict(http_gate, body, "pos_tol_m=1.5")
    assert v.approved
    assert v.tolerances.position_m == 1.5
    assert v.replay.query.startswith("map=lab&start=1.2,3.0,0.0&")


def test_start_inside_an_obstacle_is_start_in_collision(http_gate: GateServer) -> None:
    v = _verdict(http_gate, plan((5.0, 3.0, 0.0), fwd(0.5)), "start=4.0,3.0,0")
    assert v.failure_type == "start_in_collision"
    assert v.failed_step == 0
    assert v.collision is not None and v.collision.obstacle_id == "table"
    assert v.collision.time_s == 0.0
    assert v.steps == ()
    assert len(v.trajectory.samples) == 1


def test_margin_decides_whether_a_near_miss_collides(http_gate: GateServer) -> None:
    # 2 m from the start, the front stops about 0.05 m short of the table (x = 3.6).
    body = plan((3.2, 3.0, 0.0), fwd(1.0, speed=20), fwd(1.0, speed=20))
    hit = _verdict(http_gate, body, "margin_m=0.1")
    miss = _verdict(http_gate, body, "margin_m=0.0")
    assert hit.failure_type == "collision"
    assert miss.collision is None


def test_trajectory_is_tagged_per_step(http_gate: GateServer, rover: RoverDescription) -> None:
    body = plan((2.0, 3.5, 90.0), fwd(0.8), turn(rover, 90), fwd(0.5))
    v = _verdict(http_gate, body, "sample_hz=20")
    samples = v.trajectory.samples
    assert v.trajectory.sample_period_s == pytest.approx(0.05)
    assert [s.t_s for s in samples] == sorted(s.t_s for s in samples)
    for s in samples:
        st = v.steps[s.step]
        assert s.step_t_s == pytest.approx(s.t_s - st.start_time_s, abs=1e-6)
        assert s.step_t_s >= 0.0
    for st in v.steps:
        own = [s for s in samples if s.step == st.index]
        assert own[0].step_t_s == 0.0
        assert own[0].pose == st.start_pose
        ends = [s for s in own if s.t_s == st.end_time_s]
        assert ends[0].pose == st.end_pose
        assert st.expected_duration_s == pytest.approx(st.end_time_s - st.start_time_s)
        assert st.nominal_duration_s > 0
        inner = [s for s in own if 0.0 < s.step_t_s < st.expected_duration_s]
        gaps = [b.t_s - a.t_s for a, b in itertools.pairwise(inner)]
        assert all(g == pytest.approx(0.05) for g in gaps)
    last = samples[-1]
    assert last.pose == v.final_pose
    assert last.t_s == pytest.approx(v.sim_time_s)


def test_replay_record_names_map_rover_and_plan(
    http_gate: GateServer, rover: RoverDescription
) -> None:
    body = plan((2.2, 3.0, 0.0), fwd(1.0))
    v = _verdict(http_gate, body)
    r = v.replay
    assert r.seed == 0
    assert r.map_sha256 == load_map("lab").digest()
    assert r.rover_sha256 == rover.digest()
    assert r.rover == rover.name
    assert r.dt_s == 0.01
    assert r.start.x == LAB_START[0]
    # Replaying the recorded query on the recorded map reproduces the verdict.
    again = post_plan(http_gate.address, body, r.query)
    assert Verdict.from_dict(again.json()).to_dict() | {"wall_time_s": 0} == v.to_dict() | {
        "wall_time_s": 0
    }


def test_a_start_pose_from_the_query(http_gate: GateServer) -> None:
    v = _verdict(http_gate, plan((3.0, 3.0, 0.0), fwd(1.0)), "map=scn01&start=2,3,0")
    assert v.approved
    assert v.start_pose.x == 2.0 and v.start_pose.y == 3.0
    assert v.steps[0].start_pose == v.start_pose
    assert v.final_pose.x == pytest.approx(3.0, abs=0.01)


def test_rendered_picture_is_a_png_of_the_map(http_gate: GateServer) -> None:
    import base64
    import io

    from PIL import Image

    body = plan((6.2, 3.0, 0.0), *(step("FWD", 60, 30000) for _ in range(4)))
    v = _verdict(http_gate, body, "render=1")
    assert v.image_png_base64 is not None
    image = Image.open(io.BytesIO(base64.b64decode(v.image_png_base64)))
    assert image.format == "PNG"
    # 8 x 6 m at 100 px/m plus a 24 px border, and the legend band below.
    assert image.size == (848, 648 + LEGEND_PX)
    plain = _verdict(http_gate, body)
    assert plain.image_png_base64 is None
    assert plain.replay.render is False and v.replay.render is True


def test_pose2d_helpers_agree_with_the_verdict_frame() -> None:
    # A sanity anchor for the sign conventions the tests above rely on.
    assert Pose2D.from_deg(0, 0, 90).yaw_rad == pytest.approx(math.pi / 2)


def test_a_start_on_the_maps_edge_is_played_and_one_past_it_refused(
    http_gate: GateServer,
) -> None:
    """The OpenAPI document allows any start within the map's bounds, edges included
    (issue 43): a start on the west wall is played, and touches it; a step past it is a 400."""
    v = _verdict(http_gate, plan((1.0, 1.0, 0.0), fwd(0.5)), "start=0,3,0")
    assert v.failure_type == "start_in_collision"
    assert v.collision is not None and v.collision.obstacle_id == "bounds"
    outside = post_plan(http_gate.address, plan((1.0, 1.0, 0.0), fwd(0.5)), "start=-0.01,3,0")
    assert (outside.status, outside.json()["parameter"]) == (400, "start")

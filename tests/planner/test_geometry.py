"""Angles, distances and map clearance."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.plan import Goal, Plan
from firmware_proto.pose import Pose
from planner.errors import GateProtocolError
from planner.geometry import (
    point_in_polygon,
    point_segment_distance,
    segment_segment_distance,
    segments_intersect,
    wrap_deg,
    wrap_rad,
)
from planner.mapinfo import BOUNDS_ID, MapInfo

finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(finite)
def test_wrap_deg_lands_in_range_and_keeps_the_angle(angle: float) -> None:
    w = wrap_deg(angle)
    assert -180.0 <= w < 180.0
    assert math.isclose(math.cos(math.radians(w)), math.cos(math.radians(angle)), abs_tol=1e-6)
    assert math.isclose(math.sin(math.radians(w)), math.sin(math.radians(angle)), abs_tol=1e-6)


def test_wrap_examples() -> None:
    assert wrap_deg(180.0) == -180.0
    assert wrap_deg(-190.0) == 170.0
    assert wrap_deg(720.0 + 30.0) == 30.0
    assert wrap_rad(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


def test_point_segment_distance() -> None:
    assert point_segment_distance((0, 1), (-1, 0), (1, 0)) == pytest.approx(1.0)
    assert point_segment_distance((3, 4), (0, 0), (0, 0)) == pytest.approx(5.0)
    assert point_segment_distance((2, 1), (-1, 0), (1, 0)) == pytest.approx(math.sqrt(2))


def test_segments() -> None:
    assert segments_intersect((0, 0), (2, 2), (0, 2), (2, 0))
    assert segments_intersect((0, 0), (1, 0), (1, 0), (2, 5))  # touching ends
    assert not segments_intersect((0, 0), (1, 0), (0, 1), (1, 1))
    assert segment_segment_distance((0, 0), (1, 0), (0, 1), (1, 1)) == pytest.approx(1.0)
    assert segment_segment_distance((0, 0), (2, 2), (0, 2), (2, 0)) == 0.0


def test_point_in_polygon_concave() -> None:
    ell = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    assert point_in_polygon((0.5, 1.5), ell)
    assert not point_in_polygon((1.5, 1.5), ell)


def test_pose_is_the_plans_goal_and_knows_its_finiteness() -> None:
    p = Pose(1.0, 2.0, 90.0)
    stop = {"command": "STOP", "speed": 0, "distance": 0}
    assert Goal is Pose
    assert Plan.from_dict({"goal": p.to_dict(), "commands": [stop]}).goal == p
    assert p.yaw_rad == pytest.approx(math.pi / 2)
    assert not Pose(1.0, math.nan, 0.0).is_finite()


def test_clearance_on_the_lab_map(worlds: dict[str, MapInfo]) -> None:
    lab = worlds["lab"]
    d, oid = lab.clearance((3.0, 3.0))
    assert oid == "table"
    assert d == pytest.approx(0.6)
    inside, oid = lab.clearance((4.0, 3.0))
    assert oid == "table"
    assert inside == pytest.approx(-0.4)
    wall, oid = lab.clearance((0.1, 3.0))
    assert oid == BOUNDS_ID
    assert wall == pytest.approx(0.1)
    d, oid = lab.segment_clearance((1.2, 3.0), (6.2, 3.0))
    assert (d, oid) == (0.0, "table")
    assert lab.segment_blocked((2.0, 4.6), (5.0, 4.6), 0.3) is None
    assert lab.segment_blocked((2.0, 4.6), (5.0, 4.6), 1.0) == "table"
    assert lab.point_blocked((5.6, 1.7), 0.2) == "pillar"


def test_map_parsing_names_the_bad_field() -> None:
    good = {
        "bounds": {"min_x": 0, "min_y": 0, "max_x": 5, "max_y": 5},
        "start": {"x": 1, "y": 1, "yaw_deg": 0},
        "obstacles": [{"id": "a", "type": "circle", "center": [2, 2], "radius": 0.5}],
    }
    assert MapInfo.from_dict(good).obstacles[0].radius_m == 0.5
    bad = dict(good, obstacles=[{"id": "a", "type": "circle", "center": [2], "radius": 0.5}])
    with pytest.raises(GateProtocolError) as err:
        MapInfo.from_dict(bad)
    assert err.value.pointers == ("/obstacles/0/center",)
    with pytest.raises(GateProtocolError, match="/bounds"):
        MapInfo.from_dict({"start": {"x": 0, "y": 0}})

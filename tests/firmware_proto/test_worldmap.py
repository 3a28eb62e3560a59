"""The map model: schema and semantic violations reported with their JSON pointer,
loading by name or path, canonical digests, lookups and clearance queries."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.errors import MapError, ProtoError
from firmware_proto.model.worldmap import (
    BOUNDS_ID,
    MAPS_DIR,
    CircleObstacle,
    PolygonObstacle,
    SegmentObstacle,
    WorldMap,
    list_maps,
    load_map,
    validate_map,
)

VALID: dict[str, Any] = {
    "name": "tiny",
    "description": "a valid map",
    "bounds": {"min_x": 0, "min_y": 0, "max_x": 4, "max_y": 3},
    "obstacles": [
        {"id": "crate", "type": "polygon", "points": [[2, 1], [3, 1], [3, 2], [2, 2]]},
        {"id": "rock", "type": "circle", "center": [1, 2.5], "radius": 0.2},
        {"id": "rail", "type": "segment", "a": [0.5, 0.2], "b": [3.5, 0.2]},
    ],
    "traction_regions": [
        {"id": "sand", "polygon": [[0, 0], [1, 0], [1, 1], [0, 1]], "mu_scale": 0.5}
    ],
    "start": {"x": 0.8, "y": 1.5, "yaw_deg": 0},
    "goals": [{"name": "east", "x": 3.5, "y": 1.5, "yaw_deg": 0, "note": "behind the crate"}],
}


def mutated(path: str, value: Any) -> dict[str, Any]:
    """VALID with the value at a slash path replaced (``...=DELETE`` removes it)."""
    doc = copy.deepcopy(VALID)
    parts = path.strip("/").split("/")
    node: Any = doc
    for part in parts[:-1]:
        node = node[int(part)] if isinstance(node, list) else node[part]
    last = parts[-1]
    key: Any = int(last) if isinstance(node, list) else last
    if value is DELETE:
        del node[key]
    else:
        node[key] = value
    return doc


DELETE = object()

VIOLATIONS = [
    ("/colour", "red", "/colour"),
    ("/bounds", DELETE, ""),
    ("/bounds/max_x", "4", "/bounds/max_x"),
    ("/bounds/max_x", -1, "/bounds/max_x"),
    ("/obstacles/0/colour", "red", "/obstacles/0/colour"),
    ("/obstacles/0/type", "blob", "/obstacles/0/type"),
    ("/obstacles/0/points", [[0, 0], [1, 1]], "/obstacles/0/points"),
    ("/obstacles/0/points/1", [3, 1, 0], "/obstacles/0/points/1"),
    ("/obstacles/0/points", [[0, 0], [1, 1], [1, 0], [0, 1]], "/obstacles/0/points"),
    ("/obstacles/0/points", [[0, 0], [1, 0], [2, 0]], "/obstacles/0/points"),
    ("/obstacles/0/points", [[0, 0], [1, 0], [1, 1], [0, 0]], "/obstacles/0/points/3"),
    ("/obstacles/1/radius", 0, "/obstacles/1/radius"),
    ("/obstacles/1/radius", DELETE, "/obstacles/1"),
    ("/obstacles/1/id", "crate", "/obstacles/1/id"),
    ("/obstacles/1/id", BOUNDS_ID, "/obstacles/1/id"),
    ("/obstacles/1/id", "two words", "/obstacles/1/id"),
    ("/obstacles/2/b", [0.5, 0.2], "/obstacles/2/b"),
    ("/obstacles/2/radius", -0.1, "/obstacles/2/radius"),
    ("/traction_regions/0/mu_scale", 0, "/traction_regions/0/mu_scale"),
    ("/traction_regions/0/mu_scale", 2.5, "/traction_regions/0/mu_scale"),
    ("/start", {"x": 9, "y": 1, "yaw_deg": 0}, "/start"),
    ("/start/yaw_deg", math.nan, "/start/yaw_deg"),
    ("/goals/0/x", -1, "/goals/0"),
    ("/goals/0/extra", 1, "/goals/0/extra"),
    ("/name", "Has Caps", "/name"),
]


def test_the_valid_document_is_valid() -> None:
    assert validate_map(VALID) == []


@pytest.mark.parametrize(("path", "value", "pointer"), VIOLATIONS)
def test_violations_are_reported_at_their_pointer(path: str, value: Any, pointer: str) -> None:
    doc = mutated(path, value)
    found = validate_map(doc)
    assert pointer in [p for p, _ in found], found
    with pytest.raises(MapError) as info:
        WorldMap.from_dict(doc, "doc.json")
    assert info.value.violations == found
    assert (pointer or "/") in str(info.value)
    assert "doc.json" in str(info.value)


def test_duplicate_goal_names() -> None:
    doc = copy.deepcopy(VALID)
    doc["goals"].append(dict(doc["goals"][0]))
    assert ("/goals/1/name", "duplicate goal name 'east'") in validate_map(doc)


def test_map_error_is_a_value_error_and_a_protocol_error() -> None:
    assert issubclass(MapError, ValueError)
    assert issubclass(MapError, ProtoError)


def test_load_by_name_and_by_path(tmp_path: Path) -> None:
    by_name = load_map("lab")
    by_path = load_map(MAPS_DIR / "lab.json")
    assert by_name == by_path
    assert load_map(str(MAPS_DIR / "lab.json")) == by_name
    spaced = tmp_path / "lab_spaced.json"
    spaced.write_text(json.dumps(by_name.to_dict(), indent=4))
    assert load_map(spaced).digest() == by_name.digest()


def test_unknown_name_lists_the_shipped_maps() -> None:
    with pytest.raises(MapError, match="known: lab, scn01, scn02, scn03"):
        load_map("moon")


def test_unreadable_and_non_json_files(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="cannot read"):
        load_map(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(MapError, match="not valid JSON") as info:
        load_map(bad)
    assert info.value.violations[0][0] == ""


def test_list_maps() -> None:
    assert list_maps() == ("lab", "scn01", "scn02", "scn03")


def test_digest_is_canonical() -> None:
    world = WorldMap.from_dict(VALID)
    assert world.to_dict()["obstacles"][2]["radius"] == 0.0  # default filled in
    assert WorldMap.from_dict(world.to_dict()) == world
    floats = json.loads(json.dumps(VALID).replace(": 0,", ": 0.0,"))
    assert WorldMap.from_dict(floats).digest() == world.digest()
    moved = mutated("/obstacles/1/radius", 0.25)
    assert WorldMap.from_dict(moved).digest() != world.digest()
    assert len(world.digest()) == 64


def test_lookups() -> None:
    world = WorldMap.from_dict(VALID)
    assert world.goal("east").note == "behind the crate"
    rock = world.obstacle("rock")
    assert rock is not None and rock.id == "rock"
    with pytest.raises(KeyError, match="known: east"):
        world.goal("west")
    assert world.obstacle("nope") is None
    assert world.obstacle(BOUNDS_ID) is None


def test_clearance() -> None:
    world = WorldMap.from_dict(VALID)
    inside = world.clearance((2.5, 1.5))
    assert inside.obstacle_id == "crate"
    assert inside.distance_m == pytest.approx(-0.5)
    near_rock = world.clearance((1.0, 2.0))
    assert near_rock.obstacle_id == "rock"
    assert near_rock.distance_m == pytest.approx(0.3)
    near_wall = world.clearance((3.9, 2.8))
    assert near_wall.obstacle_id == BOUNDS_ID
    assert near_wall.distance_m == pytest.approx(0.1)
    assert world.clearance((2.0, 0.3)).obstacle_id == "rail"
    distance_m, obstacle_id = world.clearance((1.0, 2.0), max_m=0.1)
    assert (distance_m, obstacle_id) == (0.1, "")  # nothing that close


def test_a_point_outside_the_walls_and_inside_an_obstacle_names_the_obstacle() -> None:
    doc = mutated("/obstacles/0/points", [[3.5, 1], [4.5, 1], [4.5, 2], [3.5, 2]])
    world = WorldMap.from_dict(doc)
    found = world.clearance((4.05, 1.5))  # 0.05 m beyond the wall at x = 4
    assert found.obstacle_id == "crate"
    assert found.distance_m == pytest.approx(-0.45)


def test_clearance_on_the_lab_map() -> None:
    lab = load_map("lab")
    for point, distance_m, obstacle_id in [
        ((3.0, 3.0), 0.6, "table"),
        ((4.0, 3.0), -0.4, "table"),
        ((0.1, 3.0), 0.1, BOUNDS_ID),
    ]:
        found = lab.clearance(point)
        assert found.distance_m == pytest.approx(distance_m) and found.obstacle_id == obstacle_id
    assert lab.segment_clearance((1.2, 3.0), (6.2, 3.0)) == (0.0, "table")
    assert lab.segment_blocked((2.0, 4.6), (5.0, 4.6), 0.3) is None
    assert lab.segment_blocked((2.0, 4.6), (5.0, 4.6), 1.0) == "table"
    assert lab.point_blocked((5.6, 1.7), 0.2) == "pillar"
    assert lab.point_blocked((0.1, 3.0), 0.2) == BOUNDS_ID


def test_every_obstacle_answers_from_its_outline() -> None:
    square = PolygonObstacle("sq", ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)))
    disc = CircleObstacle("disc", (5.0, 5.0), 1.0)
    wall = SegmentObstacle("wall", (0.0, 5.0), (2.0, 5.0), 0.1)
    assert [o.kind for o in (square, disc, wall)] == ["polygon", "circle", "segment"]
    assert (square.radius_m, disc.points, wall.points) == (
        0.0,
        ((5.0, 5.0),),
        ((0.0, 5.0), (2.0, 5.0)),
    )
    assert square.distance((1.0, 1.0)) == pytest.approx(-1.0)
    assert disc.distance((5.0, 7.0)) == pytest.approx(1.0)
    assert wall.distance((1.0, 5.5)) == pytest.approx(0.4)
    assert square.segment_distance((3.0, -1.0), (3.0, 3.0)) == pytest.approx(1.0)
    assert square.segment_distance((-1.0, 1.0), (3.0, 1.0)) == 0.0
    assert disc.segment_distance((3.0, 3.0), (7.0, 3.0)) == pytest.approx(1.0)
    assert wall.segment_distance((1.0, 4.0), (1.0, 6.0)) == pytest.approx(-0.1)
    assert disc.box == (4.0, 4.0, 6.0, 6.0)
    assert wall.box == pytest.approx((-0.1, 4.9, 2.1, 5.1))
    assert square.extent_along((0.0, 0.0), (1.0, 0.0)) == (0.0, 2.0)
    assert disc.extent_along((0.0, 5.0), (1.0, 0.0)) == (4.0, 6.0)

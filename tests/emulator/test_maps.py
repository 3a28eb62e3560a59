"""The shipped maps: they load, their start poses are clear, and every suggested goal
is blocked on the straight path from the start while a detour exists."""

from __future__ import annotations

import math
from collections import deque

import pytest

from emulator.drive import turn_units_for_yaw
from emulator.playback import play
from emulator.twin import GATE_DT_S, Twin
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import MAPS_DIR, MapGoal, WorldMap, list_maps, load_map
from firmware_proto.wire.messages import Command

MAPS = list_maps()
GOALS = [(name, goal.name) for name in MAPS for goal in load_map(name).goals]

CORRIDOR_CLEARANCE_M = 0.35
"""Half the rover width (0.25 m) plus 0.1 m: a 0.7 m corridor for driving lengthwise."""

TURN_CLEARANCE_M = 0.43
"""Half the footprint diagonal: room to turn on the spot."""


def straight_plan(
    rover: RoverDescription, start: Pose, goal: MapGoal
) -> list[tuple[int, int, int]]:
    """What a naive planner sends: face the goal, drive straight, turn to the goal yaw."""
    dx, dy = goal.x - start.x, goal.y - start.y
    heading = math.atan2(dy, dx)
    steps: list[tuple[int, int, int]] = []
    for turn in (wrap_rad(heading - math.radians(start.yaw_deg)),):
        if abs(turn) > 1e-3:
            command = Command.LEFT if turn > 0 else Command.RIGHT
            steps.append((command, 30, turn_units_for_yaw(rover, turn)))
    units = rover.m_to_units(math.hypot(dx, dy))
    while units > 0:
        chunk = min(units, rover.drive.max_distance)
        steps.append((Command.FWD, 60, chunk))
        units -= chunk
    return steps


def corridor_exists(world: WorldMap, start: Pose, goal: MapGoal, cell_m: float = 0.1) -> bool:
    """Breadth-first search over grid cells whose clearance admits the rover's width."""
    b = world.bounds
    nx, ny = int(b.width_m / cell_m), int(b.height_m / cell_m)

    def centre(i: int, j: int) -> tuple[float, float]:
        return b.min_x + (i + 0.5) * cell_m, b.min_y + (j + 0.5) * cell_m

    free = [
        [world.clearance(centre(i, j)).distance_m >= CORRIDOR_CLEARANCE_M for j in range(ny)]
        for i in range(nx)
    ]
    first = (int((start.x - b.min_x) / cell_m), int((start.y - b.min_y) / cell_m))
    last = (int((goal.x - b.min_x) / cell_m), int((goal.y - b.min_y) / cell_m))
    seen = {first}
    queue = deque([first])
    while queue:
        i, j = queue.popleft()
        if (i, j) == last:
            return True
        for ni, nj in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
            if 0 <= ni < nx and 0 <= nj < ny and free[ni][nj] and (ni, nj) not in seen:
                seen.add((ni, nj))
                queue.append((ni, nj))
    return False


@pytest.mark.parametrize("name", MAPS)
def test_map_loads_and_is_named_after_its_file(name: str) -> None:
    world = load_map(name)
    assert world.name == name
    assert (MAPS_DIR / f"{name}.json").is_file()
    assert world.goals, "every shipped map suggests goals"
    assert len({o.id for o in world.obstacles}) == len(world.obstacles)


@pytest.mark.parametrize("name", MAPS)
def test_start_pose_is_clear(rover: RoverDescription, name: str) -> None:
    world = load_map(name)
    assert world.clearance((world.start.x, world.start.y)).distance_m >= TURN_CLEARANCE_M
    assert Twin(rover, world).first_collision is None


@pytest.mark.parametrize(("name", "goal_name"), GOALS)
def test_goal_is_blocked_straight_but_reachable(
    rover: RoverDescription, name: str, goal_name: str
) -> None:
    world = load_map(name)
    goal = world.goal(goal_name)
    clearance = world.clearance((goal.x, goal.y)).distance_m
    assert clearance >= CORRIDOR_CLEARANCE_M + 0.1 - 1e-9, "room to stand at the goal"
    assert corridor_exists(world, world.start, goal), "a detour exists"
    result = play(Twin(rover, world, dt_s=GATE_DT_S), straight_plan(rover, world.start, goal))
    assert result.collision is not None, "the straight path must collide"
    assert result.collision.obstacle_id != "bounds"


def test_scenarios_grow_denser(rover: RoverDescription) -> None:
    counts = [len(load_map(n).obstacles) for n in ("scn01", "scn02", "scn03")]
    assert counts == sorted(counts)
    assert counts[0] < counts[2]
    for name in ("scn01", "scn02", "scn03"):
        b = load_map(name).bounds
        assert (b.width_m, b.height_m) == (12.0, 8.0)


@pytest.mark.parametrize(
    ("x", "y"),
    [(6.1, 2.8), (6.1, 5.5), (10.05, 6.2)],
    ids=["barrier-south", "barrier-north", "boulder-gap"],
)
def test_scn03_narrow_passages_fit_the_rover_with_room(x: float, y: float) -> None:
    """Each designed passage is 0.9 m wide: the 0.7 m footprint length plus 0.2 m, so
    the 0.5 m wide rover passes lengthwise with 0.2 m to spare on each side."""
    world = load_map("scn03")
    assert world.clearance((x, y)).distance_m >= 0.45 - 1e-9

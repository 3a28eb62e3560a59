"""Plan schema (thesis Listing 1): valid plans build; every violation has its pointer."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest

from firmware_proto.errors import PlanError
from firmware_proto.model.plan import Plan, PlanStep, plan_schema, validate_plan

GOOD: dict[str, Any] = {
    "goal": {"x": 1.5, "y": -2, "yaw_deg": 90},
    "commands": [
        {"command": "LEFT", "speed": 20, "distance": 7000},
        {"command": "FWD", "speed": 60, "distance": 30000},
        {"command": "STOP", "speed": 0, "distance": 0},
    ],
}


def _with(path: list[Any], value: Any) -> dict[str, Any]:
    plan = copy.deepcopy(GOOD)
    target = plan
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return plan


_DELETE = object()


def test_good_plan_builds_and_maps_to_wire_codes() -> None:
    plan = Plan.from_dict(GOOD)
    assert plan.to_wire() == [(3, 20, 7000), (1, 60, 30000), (0, 0, 0)]
    assert Plan.from_json(plan.to_json()) == plan
    assert PlanStep.from_wire(4, 10, 5) == PlanStep("RIGHT", 10, 5)


def test_schema_is_listing_1() -> None:
    schema = plan_schema()
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    step = schema["$defs"]["command_step"]["properties"]
    assert step["speed"] == {"type": "integer", "minimum": 0, "maximum": 60}
    assert step["distance"] == {"type": "integer", "minimum": 0, "maximum": 30000}
    assert schema["properties"]["commands"]["maxItems"] == 12


@pytest.mark.parametrize(
    ("plan", "pointer"),
    [
        (_with(["extra"], 1), "/extra"),
        (_with(["goal", "z"], 0), "/goal/z"),
        (_with(["commands", 0, "note"], "x"), "/commands/0/note"),
        (_with(["commands"], []), "/commands"),
        (_with(["commands"], [GOOD["commands"][1]] * 13), "/commands"),
        (_with(["commands", 1, "speed"], 61), "/commands/1/speed"),
        (_with(["commands", 1, "speed"], -1), "/commands/1/speed"),
        (_with(["commands", 1, "distance"], -1), "/commands/1/distance"),
        (_with(["commands", 1, "distance"], 30001), "/commands/1/distance"),
        (_with(["commands", 0, "command"], "JUMP"), "/commands/0/command"),
        (_with(["commands", 0, "speed"], "20"), "/commands/0/speed"),
        (_with(["commands", 0, "speed"], 20.5), "/commands/0/speed"),
        (_with(["commands", 0, "speed"], True), "/commands/0/speed"),
        (_with(["goal", "x"], "1"), "/goal/x"),
        (_with(["goal", "x"], float("nan")), "/goal/x"),
        (_with(["goal", "yaw_deg"], float("inf")), "/goal/yaw_deg"),
        (_with(["goal", "y"], _DELETE), ""),
        (_with(["commands"], "FWD"), "/commands"),
        (_with(["commands", 2, "distance"], _DELETE), "/commands/2"),
    ],
)
def test_each_violation_is_reported_at_its_pointer(plan: dict[str, Any], pointer: str) -> None:
    violations = validate_plan(plan)
    assert pointer in [p for p, _ in violations] or (
        pointer == "" and any(p == "/goal" for p, _ in violations)
    ), violations
    with pytest.raises(PlanError) as info:
        Plan.from_dict(plan)
    assert info.value.violations == violations


def test_several_violations_are_all_reported() -> None:
    plan = _with(["commands", 0, "speed"], 99)
    plan["commands"][1]["distance"] = -5
    plan["bogus"] = True
    pointers = [p for p, _ in validate_plan(plan)]
    assert pointers == ["/bogus", "/commands/0/speed", "/commands/1/distance"]


def test_not_json_is_a_plan_error() -> None:
    with pytest.raises(PlanError, match="not valid JSON"):
        Plan.from_json("{nope")
    with pytest.raises(PlanError):
        Plan.from_json(json.dumps([1, 2]))


def test_integral_floats_are_accepted_as_integers_and_stored_as_int() -> None:
    plan = Plan.from_dict(_with(["commands", 0, "speed"], 20.0))
    assert plan.commands[0].speed == 20 and isinstance(plan.commands[0].speed, int)

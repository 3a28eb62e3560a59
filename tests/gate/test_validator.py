"""The validator in-process: no tunnelling through thin walls at top speed, the stall
verdict, maps given as files, determinism across repeated runs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from emulator.twin import Twin
from firmware_proto.model.plan import Plan
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap
from gate.config import GateConfig, PlaybackSettings
from gate.errors import GateConfigError, OptionError
from gate.options import ValidateOptions
from gate.validator import Job, Validator, load_maps

from .plans import plan, step

THIN_WALL = {
    "name": "thin",
    "description": "a zero-thickness wall across a corridor",
    "bounds": {"min_x": 0, "min_y": 0, "max_x": 12, "max_y": 12},
    "obstacles": [
        {"id": "sheet", "type": "segment", "a": [6.0, 1.0], "b": [6.0, 11.0], "radius": 0.0}
    ],
    "traction_regions": [],
    "start": {"x": 1.0, "y": 6.0, "yaw_deg": 0},
}


@pytest.fixture(scope="module")
def thin_validator(rover: RoverDescription) -> Validator:
    world = WorldMap.from_dict(THIN_WALL)
    return Validator(rover, {"thin": world}, PlaybackSettings(), "thin")


def _validate(v: Validator, body: dict[str, object], query: str = "") -> Verdict:
    options = ValidateOptions.from_query(query).resolve(v.settings, v.default_map)
    return v.validate(Plan.from_dict(body), options)


@pytest.mark.parametrize("margin", [0.0, 0.1])
@pytest.mark.parametrize("heading", [0.0, 17.0, -20.0])
def test_no_tunnelling_through_a_zero_thickness_wall_at_top_speed(
    thin_validator: Validator, margin: float, heading: float
) -> None:
    # Start 4 m west of the wall, facing it at an angle, four steps at top speed.
    body = plan((11.0, 6.0, 0.0), *(step("FWD", 60, 30000) for _ in range(4)))
    v = _validate(thin_validator, body, f"start=2,6,{heading}&margin_m={margin}")
    assert v.failure_type == "collision"
    assert v.collision is not None and v.collision.obstacle_id == "sheet"
    assert v.collision.contact.x == pytest.approx(6.0, abs=1e-9)
    # The contact is caught within one step's travel (3 mm at 0.3 m/s and 10 ms) of the
    # first touch: the footprint's leading corner plus the margin (the inflated shape
    # has rounded corners) is at the wall.
    yaw = math.radians(v.collision.pose.yaw_deg)
    reach = 0.35 * abs(math.cos(yaw)) + 0.25 * abs(math.sin(yaw)) + margin
    assert v.collision.pose.x + reach == pytest.approx(6.0, abs=0.004)
    assert all(s.pose.x < 6.0 for s in v.trajectory.samples)


def test_a_locked_wheel_stalls(rover: RoverDescription, validator: Validator) -> None:
    class LockedLeft(Validator):
        """The one hook a subclass may override: the twin a job plays on."""

        def _make_twin(self, job: Job) -> Twin:
            twin = super()._make_twin(job)
            twin.set_wheel_locked("left", True)
            return twin

    v = LockedLeft(rover, validator.maps, validator.settings, "lab")
    verdict = _validate(v, plan((2.2, 3.0, 0.0), step("LEFT", 30, 3000), step("FWD", 30, 23000)))
    assert verdict.failure_type == "stalled"
    assert verdict.failed_step == 0
    assert verdict.stall is not None
    assert (verdict.stall.step, verdict.stall.reason, verdict.stall.side) == (
        0,
        "no_encoder_progress",
        "left",
    )
    assert "left side" in verdict.failure_reason


def test_repeated_runs_are_bit_identical(validator: Validator) -> None:
    body = plan(
        (5.0, 1.0, -90.0),
        step("RIGHT", 30, 8000),
        step("FWD", 60, 30000),
        step("LEFT", 20, 4000),
        step("FWD", 30, 20000),
    )
    first = _validate(validator, body, "render=1")
    for _ in range(2):
        again = _validate(validator, body, "render=1")
        assert again.to_dict() | {"wall_time_s": 0} == first.to_dict() | {"wall_time_s": 0}


def test_options_checked_against_the_maps(validator: Validator) -> None:
    body = plan((2.0, 3.0, 0.0), step("FWD", 30, 1000))
    with pytest.raises(OptionError) as info:
        _validate(validator, body, "map=nowhere")
    assert info.value.parameter == "map"
    with pytest.raises(OptionError) as info:
        _validate(validator, body, "start=-1,3,0")
    assert info.value.parameter == "start"


def test_a_map_file_becomes_the_default_and_is_served(tmp_path: Path) -> None:
    path = tmp_path / "thin.json"
    path.write_text(json.dumps(THIN_WALL))
    maps, default = load_maps(str(path))
    assert default == "thin" and {"lab", "scn03", "thin"} <= set(maps)
    v = Validator.from_config(GateConfig(default_map=str(path)))
    assert v.default_map == "thin"
    clash = dict(THIN_WALL, name="lab")
    path.write_text(json.dumps(clash))
    with pytest.raises(GateConfigError, match="like a different shipped map"):
        load_maps(str(path))
    with pytest.raises(GateConfigError):
        load_maps(str(tmp_path / "missing.json"))

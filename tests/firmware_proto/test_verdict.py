"""The verdict's one codec: its JSON is pinned byte for byte (the gate's answers stay what
clients read), reads back equal, names the pointer of a bad field, and validates against
the schema generated from the same dataclasses."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from jsonschema import Draft202012Validator, ValidationError

from firmware_proto.errors import VerdictError
from firmware_proto.model.pose import Point, Pose
from firmware_proto.model.verdict import (
    CollisionReport,
    EnvelopePoint,
    GoalErrorPercentiles,
    ObstacleHits,
    Replay,
    StallReport,
    StepPrediction,
    Tolerances,
    Trajectory,
    TrajectorySample,
    Uncertainty,
    Verdict,
    verdict_schemas,
)

PINNED = Path(__file__).parent / "data" / "verdicts"
SHA = "0" * 63 + "1"
START = Pose(1.2, 3.0, 0.0)
END = Pose(2.1966, 3.0, -0.5)
TOLERANCES = Tolerances(0.1, 3.0, 0.1)


def _replay(seed: int = 0, render: bool = False) -> Replay:
    query = "map=lab&start=1.2,3.0,0.0"
    return Replay(
        seed, "lab", SHA, "rassor-lab", SHA, SHA, START, 0.01, 10.0, render, "0.1.0", "7.3.1", query
    )


def _step(completed: bool = True) -> StepPrediction:
    return StepPrediction(
        0, "FWD", 40, 23000, 0.0, 5.25, 5.25, 5.25, START, END, completed, 23000.0, 22999.5
    )


TRAJECTORY = Trajectory(
    0.1, (TrajectorySample(0.0, 0, 0.0, START), TrajectorySample(5.25, 0, 5.25, END))
)
VERDICTS = {
    "approved": Verdict(
        True,
        None,
        "",
        None,
        Pose(2.2, 3.0, 0.0),
        START,
        END,
        0.0034,
        0.0,
        0.0034,
        0.5,
        0.0,
        None,
        None,
        TOLERANCES,
        (_step(),),
        TRAJECTORY,
        6.25,
        _replay(),
        wall_time_s=0.027656,
    ),
    "collision": Verdict(
        False,
        "collision",
        "hit rock-1",
        0,
        Pose(5.0, 3.0, 0.0),
        START,
        END,
        2.8,
        -0.25,
        2.81,
        0.5,
        0.0,
        CollisionReport("rock-1", Point(2.5, 3.1), END, 5.25, 0, 5.25),
        None,
        TOLERANCES,
        (_step(completed=False),),
        TRAJECTORY,
        5.25,
        _replay(render=True),
        image_png_base64="iVBORw0KGgo=",
        wall_time_s=0.5,
    ),
    "stalled": Verdict(
        False,
        "stalled",
        "no progress on the left",
        0,
        Pose(5.0, 3.0, 90.0),
        START,
        START,
        3.8,
        0.0,
        3.8,
        90.0,
        0.0,
        None,
        StallReport(0, "no_encoder_progress", "left", 1.0),
        TOLERANCES,
        (),
        Trajectory(0.1, ()),
        1.0,
        _replay(),
    ),
    "uncertain": Verdict(
        True,
        None,
        "",
        None,
        Pose(2.2, 3.0, 0.0),
        START,
        END,
        0.0034,
        0.0,
        0.0034,
        0.5,
        0.0,
        None,
        None,
        TOLERANCES,
        (_step(),),
        TRAJECTORY,
        6.25,
        _replay(seed=7),
        Uncertainty(
            20,
            7,
            "default",
            0.1,
            0.05,
            0.0,
            0.9,
            (ObstacleHits("bounds", 1, 0, Point(2.0, 0.0)),),
            GoalErrorPercentiles(
                19,
                (5.0, 50.0, 95.0),
                (0.01, 0.02, 0.05),
                (0.0, 0.01, 0.04),
                (-0.01, 0.0, 0.01),
                (-1.0, 0.0, 1.5),
            ),
            0.95,
            (EnvelopePoint(0, 5.25, 19, Pose(2.19, 3.0, -0.4), 0.05, 0.02, 10.0, 0.8),),
        ),
        wall_time_s=1.5,
    ),
}


def _validator() -> Draft202012Validator:
    return Draft202012Validator(
        {"$ref": "#/$defs/Verdict", "$defs": verdict_schemas(ref="#/$defs/")}
    )


@pytest.mark.parametrize("name", sorted(VERDICTS))
def test_the_json_of_a_verdict_is_pinned_byte_for_byte(name: str) -> None:
    assert VERDICTS[name].to_json() == (PINNED / f"{name}.json").read_text()


@pytest.mark.parametrize("name", sorted(VERDICTS))
def test_a_verdict_reads_back_equal_and_validates_against_its_generated_schema(
    name: str,
) -> None:
    verdict = VERDICTS[name]
    assert Verdict.from_json(verdict.to_json()) == verdict
    assert Verdict.from_dict(json.loads(verdict.to_json())) == verdict
    _validator().validate(verdict.to_dict())


def test_keys_keep_the_documented_order_and_optional_ones_are_left_out() -> None:
    keys = list(VERDICTS["approved"].to_dict())
    assert keys[:2] == ["approved", "failure_type"] and keys[-2:] == ["replay", "wall_time_s"]
    assert "uncertainty" not in keys and "image_png_base64" not in keys
    keys = list(VERDICTS["collision"].to_dict())
    assert keys[-2:] == ["image_png_base64", "wall_time_s"]


def test_the_generated_schema_refuses_what_the_codec_would_never_write() -> None:
    data: dict[str, Any] = VERDICTS["collision"].to_dict()
    for broken in (
        data | {"extra": 1},
        data | {"failure_type": "on_fire"},
        data | {"failed_step": 12},
        data | {"uncertainty": None},
        {k: v for k, v in data.items() if k != "wall_time_s"},
        data | {"trajectory": {"sample_period_s": 0.1, "samples": [{"t_s": 0.0}]}},
    ):
        with pytest.raises(ValidationError):
            _validator().validate(broken)
    schemas = verdict_schemas()
    assert schemas["Verdict"]["properties"]["collision"] == {
        "oneOf": [{"$ref": "#/components/schemas/CollisionReport"}, {"type": "null"}]
    }
    assert set(schemas["TrajectorySample"]["properties"]) == {
        "t_s",
        "step",
        "step_t_s",
        "x",
        "y",
        "yaw_deg",
    }


@pytest.mark.parametrize(
    ("edit", "pointer", "words"),
    [
        (lambda d: d.pop("final_pose"), "/final_pose", "missing field /final_pose"),
        (lambda d: d["steps"][0].update(speed="fast"), "/steps/0/speed", "not an integer"),
        (lambda d: d["steps"][0].update(completed=1), "/steps/0/completed", "not a boolean"),
        (lambda d: d["goal"].update(x=True), "/goal/x", "not a number"),
        (lambda d: d["trajectory"].update(samples={}), "/trajectory/samples", "not a list"),
        (
            lambda d: d["trajectory"]["samples"][1].pop("yaw_deg"),
            "/trajectory/samples/1/yaw_deg",
            "missing field",
        ),
        (
            lambda d: d["uncertainty"]["goal_error"].update(lateral_m=[0.1, "x"]),
            "/uncertainty/goal_error/lateral_m",
            "not a list of numbers",
        ),
        (lambda d: d.update(replay=[]), "/replay", "/replay is not an object"),
        (
            lambda d: d["uncertainty"]["collisions"][0]["contact"].pop("y"),
            "/uncertainty/collisions/0/contact/y",
            "missing field",
        ),
    ],
)
def test_a_bad_field_is_named_by_its_pointer(edit: Any, pointer: str, words: str) -> None:
    data = VERDICTS["uncertain"].to_dict()
    edit(data)
    with pytest.raises(VerdictError) as err:
        Verdict.from_dict(data)
    assert err.value.pointers == (pointer,)
    assert words in str(err.value) and str(err.value).startswith("verdict: ")


def test_reading_is_lenient_about_what_it_does_not_use() -> None:
    data = VERDICTS["approved"].to_dict()
    data["newer_field"] = {"anything": [1]}
    data["collision"] = None
    del data["wall_time_s"]
    data["steps"][0]["speed"] = 40
    data["goal"]["x"] = 2  # an integer is a number
    verdict = Verdict.from_dict(data)
    assert verdict.wall_time_s == 0.0 and verdict.goal.x == 2.0
    assert isinstance(verdict.goal.x, float)
    assert verdict == VERDICTS["approved"].__class__(
        **{**VERDICTS["approved"].__dict__, "wall_time_s": 0.0, "goal": Pose(2.0, 3.0, 0.0)}
    )
    with pytest.raises(VerdictError) as err:
        Verdict.from_json(b"{not json")
    assert err.value.pointers == ("",)

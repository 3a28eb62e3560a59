"""The gate's step error (gate.ensemble.step_error): the model discrepancy a calibrated
twin states, estimated per plan as the nominal twin's final pose at a finer step less at
the gate's, drawn in antithetic shares and carried by the verdict's final poses."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from emulator.batch import BatchDraw
from emulator.calibration import STEP_ERROR_SCALE, Calibration, Noise, Residuals
from emulator.errors import GroundError
from emulator.ground import Ground
from emulator.playback import play
from emulator.twin import Pose2D, Twin
from emulator.twinfile import load_twin, write_twin
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap, load_map
from gate.config import PlaybackSettings
from gate.ensemble import (
    STEP_ERROR_DT_S,
    ChunkJob,
    DefaultSpread,
    draw,
    run_chunk,
    step_error,
)
from gate.options import ValidateOptions
from gate.validator import Validator
from sim.calibration_runs import field_map

STEPS = [(1, 45, 23000), (3, 30, 12000), (1, 60, 17000), (4, 20, 9000), (2, 25, 11000)]
"""FWD 1 m, LEFT, FWD, RIGHT, REV, back to back: turns starting while a step brakes."""
PLAN = {
    "goal": {"x": 21.5, "y": 20.8, "yaw_deg": 30.0},
    "commands": [
        {"command": c, "speed": s, "distance": d}
        for c, s, d in [("FWD", 45, 23000), ("LEFT", 30, 12000), ("FWD", 60, 17000)]
    ],
}
START = Pose2D(20.0, 20.0, 0.0)


@pytest.fixture(scope="module")
def rover() -> RoverDescription:
    return load_rover()


@pytest.fixture(scope="module")
def field() -> WorldMap:
    return field_map()


def calibration(rover: RoverDescription, scale: float, **noise: float) -> Calibration:
    """A calibration of the description's ground with nothing uncertain but what is
    given: no parameters fitted, the start's noise as given, ``scale`` of step error."""
    zero = Residuals(0.0, 0.0, 0.0, 0)
    return Calibration(
        ground=Ground.of_rover(rover),
        parameters=(),
        covariance=(),
        before=zero,
        after=zero,
        reduced_chi2=1.0,
        driving_s=30.0,
        sources=(),
        map_name=None,
        dt_s=0.01,
        turn_efficiency=rover.traction.turn_efficiency,
        noise=Noise(0.0, noise.get("position", 0.0), noise.get("heading", 0.0)),
        step_error_scale=scale,
    )


def test_the_step_error_is_the_finer_step_less_the_gates(
    rover: RoverDescription, field: WorldMap
) -> None:
    ground = Ground.of_rover(rover)
    error = step_error(rover, field, ground, STEPS, dt_s=0.01, safety_margin_m=0.0, start=START)
    finals = [
        play(Twin(rover, field, dt_s=dt, start=START), STEPS).final_pose for dt in (0.01, 0.002)
    ]
    assert STEP_ERROR_DT_S == 0.002
    assert error[0] == pytest.approx(finals[1].x_m - finals[0].x_m, abs=1e-12)
    assert error[1] == pytest.approx(finals[1].y_m - finals[0].y_m, abs=1e-12)
    assert error[2] == pytest.approx(finals[1].yaw_rad - finals[0].yaw_rad, abs=1e-12)
    # Millimetres and hundredths of a degree: what the gate's step leaves (docs/twin.md).
    assert 1e-5 < math.hypot(error[0], error[1]) < 0.02
    assert 1e-5 < abs(error[2]) < math.radians(1.0)
    # No finer step, no error.
    same = step_error(rover, field, ground, STEPS, dt_s=0.002, safety_margin_m=0.0, start=START)
    assert same == (0.0, 0.0, 0.0)


def test_a_plan_that_collides_has_no_step_error(rover: RoverDescription) -> None:
    lab = load_map("lab")
    start = Pose2D.from_deg(lab.start.x, lab.start.y, lab.start.yaw_deg)
    into_the_table = [(1, 60, 30000), (1, 60, 30000)]
    error = step_error(
        rover, lab, Ground.of_rover(rover, lab), into_the_table,
        dt_s=0.01, safety_margin_m=0.1, start=start,
    )  # fmt: skip
    assert error == (0.0, 0.0, 0.0)


def test_the_shares_are_drawn_last_antithetic_and_scaled(rover: RoverDescription) -> None:
    # The start's own noise, given with the plan, replaces the calibration's rests'.
    spread = calibration(rover, 0.5, position=0.002, heading=0.002)
    own = draw(spread, 200, 5, 0.05, (0.001, 0.0005))
    kept = draw(spread, 200, 5, 0.05, (None, 0.0005))
    default = draw(spread, 200, 5, 0.05)
    for a, b, c in zip(own, kept, default, strict=True):
        assert a.start_dx_m == pytest.approx(b.start_dx_m / 2.0)
        assert a.start_dyaw_rad == b.start_dyaw_rad == pytest.approx(c.start_dyaw_rad / 4.0)
        assert b.start_dx_m == c.start_dx_m and a.step_error == c.step_error
    without = draw(calibration(rover, 0.0, position=0.002, heading=0.002), 200, 5, 0.05)
    with_it = draw(calibration(rover, 1.0, position=0.002, heading=0.002), 200, 5, 0.05)
    doubled = draw(calibration(rover, 2.0, position=0.002, heading=0.002), 200, 5, 0.05)
    # Everything drawn before the shares is what a spread without them draws.
    assert [replace(d, step_error=0.0) for d in with_it] == without
    assert all(d.step_error == 0.0 for d in without)
    shares = np.array([d.step_error for d in with_it])
    assert np.array_equal(shares[0::2], -shares[1::2])  # mirrored pairs: centred
    assert 0.8 < shares.std() < 1.2
    assert np.allclose([d.step_error for d in doubled], 2.0 * shares)
    # Without a calibration there is no stated discrepancy.
    assert all(d.step_error == 0.0 for d in draw(DefaultSpread(Ground.of_rover(rover)), 20, 5, 0.1))


def test_each_final_pose_moves_by_its_share_of_the_step_error(
    rover: RoverDescription, field: WorldMap
) -> None:
    ground = Ground.of_rover(rover)
    shares = (1.0, -1.0, 0.5, 0.0)
    draws = tuple(BatchDraw(ground, step_error=s) for s in shares)
    start = Pose(START.x_m, START.y_m, 0.0)
    plain = run_chunk(ChunkJob(rover, field, draws, tuple(STEPS), 0.01, 0.0, start))
    moved = run_chunk(ChunkJob(rover, field, draws, tuple(STEPS), 0.01, 0.0, start, ground))
    error = np.array(
        step_error(rover, field, ground, STEPS, dt_s=0.01, safety_margin_m=0.0, start=START)
    )
    assert np.allclose(moved.final - plain.final, np.outer(shares, error), atol=1e-12)
    # A mirrored pair stays centred on the nominal final pose.
    assert np.allclose(moved.final[:2].mean(axis=0), plain.final[0], atol=1e-12)
    # The paths (envelope) and the collisions are the twins' own.
    assert np.array_equal(moved.poses, plain.poses, equal_nan=True)
    assert np.array_equal(moved.collision_tick, plain.collision_tick)


def uncertain(validator: Validator, plan: dict[str, Any], query: str) -> Verdict:
    options = ValidateOptions.from_query(query).resolve(validator.settings, "field")
    return validator.validate_uncertain(validator.prepare(Plan.from_dict(plan), options))


def test_the_verdicts_bands_carry_the_step_error(rover: RoverDescription, field: WorldMap) -> None:
    def bands(scale: float) -> Verdict:
        validator = Validator(
            rover, {"field": field}, PlaybackSettings(), "field", spread=calibration(rover, scale)
        )
        return uncertain(validator, PLAN, "samples=40&seed=3&slip_sigma=0")

    none, stated = bands(0.0), bands(STEP_ERROR_SCALE)
    u0, u1 = none.uncertainty, stated.uncertainty
    assert u0 is not None and u1 is not None
    # Nothing uncertain but the step error: without it every twin ends where the
    # nominal one does; with it the goal errors spread about the nominal's.
    assert u0.goal_error.position_m[0] == u0.goal_error.position_m[2]
    lo, mid, hi = u1.goal_error.position_m
    assert lo < mid < hi
    assert mid == pytest.approx(u0.goal_error.position_m[1], abs=2e-4)
    assert u1.envelope == u0.envelope
    assert (
        uncertain(
            Validator(
                rover,
                {"field": field},
                PlaybackSettings(),
                "field",
                spread=calibration(rover, STEP_ERROR_SCALE),
            ),
            PLAN,
            "samples=40&seed=3&slip_sigma=0",
        ).uncertainty
        == u1
    )


def test_the_twin_file_carries_the_scale_and_an_old_one_has_none(
    rover: RoverDescription, tmp_path: Path
) -> None:
    path = tmp_path / "twin.toml"
    write_twin(path, rover, calibration(rover, STEP_ERROR_SCALE, position=0.002))
    assert load_twin(path).calibration.step_error_scale == STEP_ERROR_SCALE
    # A file written when a calibration stated the whole step error keeps its scale.
    path = tmp_path / "stated-one.toml"
    write_twin(path, rover, calibration(rover, 1.0, position=0.002))
    assert load_twin(path).calibration.step_error_scale == 1.0
    old = tmp_path / "old.toml"
    text = path.read_text(encoding="utf-8")
    assert "step_error_scale = 1.0\n" in text
    old.write_text(text.replace("step_error_scale = 1.0\n", ""), encoding="utf-8")
    loaded = load_twin(old).calibration
    assert loaded.step_error_scale == 0.0 and loaded.noise is not None
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("step_error_scale = 1.0", "step_error_scale = -1.0"))
    with pytest.raises(GroundError, match="step_error_scale"):
        load_twin(bad)

"""``rover calibrate``: read a recorded mission, measure its steps, fit the ground, write
a twin file the gate plays on; refuse what cannot be identified.

Recordings are made in lockstep (``sim.calibration_runs``: the controller model on a
ground of its own, the bridge's odometry, the same MCAP writer as a real run); one made
by the real stack is calibrated in ``tests/planner/test_calibrate_real.py``.
"""

from __future__ import annotations

import functools
import json
import math
import os
import random
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from emulator.calibration import Calibration
from emulator.errors import RecordingError, UnidentifiableError
from emulator.fit import fit_ground
from emulator.ground import load_ground
from emulator.observations import observe_steps
from emulator.playback import measure_turn_efficiency, play
from emulator.recording import RecordedStep, _status, read_recording
from emulator.twin import Pose2D, Twin
from emulator.twinfile import load_twin, write_twin
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap
from planner.record.mcaprec import record_messages
from sim.calibration_runs import drive_lockstep, field_map, random_mission
from tests.child import run_rover

LEFT, RIGHT, FWD = 3, 4, 1


rover_cli = functools.partial(run_rover, timeout_s=300.0)


@pytest.fixture(scope="module")
def field(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("map") / "field.json"
    path.write_text(field_map().to_json())
    return path


@pytest.fixture(scope="module")
def loose_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """About 55 s of driving on the loose ground, recorded as the demo records."""
    rover = load_rover()
    steps = random_mission(rover, random.Random(12), 40, max_driving_s=60.0)
    path = tmp_path_factory.mktemp("rec") / "loose.mcap"
    ground = load_ground("loose", rover)
    mission = drive_lockstep(rover, field_map(), ground, steps, seed=3, namespace="/ground")
    record_messages(path, mission.messages)
    assert mission.completed == len(steps)
    return path


@pytest.fixture(scope="module")
def fitted(twin_file: Path) -> Calibration:
    """The fit ``rover calibrate`` wrote (one fit of the recording for the module: the
    fit in process is the regions' tests below)."""
    return load_twin(twin_file).calibration


def test_a_recording_is_read_with_every_step_and_its_fate(loose_recording: Path) -> None:
    rec = read_recording(loose_recording)
    assert rec.namespace == "/ground"
    assert rec.steps and all(s.completed for s in rec.steps)
    assert all(s.accepted_s is not None and s.ended_s is not None for s in rec.steps)
    assert rec.downlink_delay_s == pytest.approx(1.5, abs=1e-3)
    assert len(rec.pose_t_s) > 10 * len(rec.steps)
    observed = observe_steps([rec], load_rover())
    assert len(observed.observations) == len(rec.steps)
    assert observed.skipped == ()


def test_statuses_answer_steps_first_in_first_out() -> None:
    from collections import deque

    steps = [RecordedStep(i, FWD, 30, 23000, float(i)) for i in range(4)]
    unanswered, running = deque(steps), deque[RecordedStep]()
    statuses = ["rejected:queue_full", "accepted", "fault:imu_lost", "completed", "accepted"]
    statuses += ["aborted:stop", "aborted:stop"]
    for t, text in enumerate(statuses):
        _status(text, float(t), unanswered, running)
    assert [s.outcome for s in steps] == [
        "rejected:queue_full",
        "completed",
        "aborted:stop",
        "aborted:stop",
    ]
    assert steps[1].faults == ["fault:imu_lost"] and steps[3].accepted_s is None


def test_the_fit_finds_the_ground_the_gate_did_not_know(fitted: Calibration) -> None:
    rover = load_rover()
    truth = load_ground("loose", rover)
    true_efficiency = measure_turn_efficiency(
        truth.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2)
    )
    assert fitted.turn_efficiency == pytest.approx(true_efficiency, abs=0.005)
    assert fitted.before.yaw_deg > 3.0
    assert fitted.after.yaw_deg < 0.2
    assert fitted.after.forward_m < fitted.before.forward_m
    assert fitted.parameters == (
        "mu_longitudinal",
        "mu_lateral",
        "slip_saturation_mps",
        "slip_saturation_ratio",
        "rolling_resistance",
    )
    for name in fitted.parameters:
        assert 0.0 < fitted.relative_sigma(name) < 0.7
        lo, hi = fitted.interval(name)
        assert lo < fitted.value(name) < hi


def test_the_twin_file_round_trips_and_loads_as_a_rover(
    fitted: Calibration, tmp_path: Path
) -> None:
    path = tmp_path / "twin.toml"
    write_twin(path, load_rover(), fitted)
    twin = load_twin(path)
    assert twin.ground.values() == pytest.approx(fitted.ground.values())
    assert np.allclose(twin.calibration.covariance, fitted.covariance)
    assert twin.calibration.after == fitted.after
    plain = load_rover(path)  # the planner reads it as a description
    assert plain.traction.turn_efficiency == pytest.approx(fitted.turn_efficiency, abs=1e-4)
    assert plain.traction.mu_lateral == pytest.approx(fitted.ground.mu_lateral)


def test_sampling_the_uncertainty_is_seeded(fitted: Calibration) -> None:
    first = fitted.sample(7, 200)
    assert first == fitted.sample(7, 200)
    assert first != fitted.sample(8, 200)
    assert fitted.sample(1, 0) == []
    # Grounds come from the posterior's draws (docs/twin.md: not the Gaussian's tails).
    assert len(fitted.draws) == 100
    drawn = {tuple(round(v, 5) for v in row) for row in fitted.draws}
    for ground in first:
        row = tuple(round(math.log(ground.values()[p]), 5) for p in fitted.parameters)
        assert row in drawn
    for name in fitted.parameters:
        lo, hi = fitted.interval(name)
        column = [math.exp(r[fitted.parameters.index(name)]) for r in fitted.draws]
        assert min(column) <= lo <= hi <= max(column)
    # Without draws, the Gaussian of the covariance, in mirrored pairs on request.
    gaussian = replace(fitted, draws=())
    logs = np.log([[g.values()[p] for p in fitted.parameters] for g in gaussian.sample(7, 400)])
    for i, name in enumerate(fitted.parameters):
        assert np.std(logs[:, i]) == pytest.approx(fitted.relative_sigma(name), rel=0.25)
    pairs = np.log(
        [[g.values()[p] for p in fitted.parameters] for g in gaussian.sample(7, 4, antithetic=True)]
    )
    centre = np.log([fitted.value(p) for p in fitted.parameters])
    assert np.allclose(pairs[0] + pairs[1], 2 * centre)


@pytest.fixture(scope="module")
def twin_file(loose_recording: Path, field: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("twin") / "twin.toml"
    done = rover_cli("calibrate", str(loose_recording), "--map", str(field), "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert "turn_efficiency" in done.stdout and f"twin written to {out}" in done.stdout
    return out


def _quarter_turn_plan() -> dict[str, object]:
    quarter = load_rover().turn_units_for_yaw(math.pi / 2)
    return {
        "goal": {"x": 20.0, "y": 20.0, "yaw_deg": 90.0},
        "commands": [{"command": "LEFT", "speed": 30, "distance": quarter}],
    }


def _true_quarter_turn_deg() -> float:
    rover = load_rover()
    steps = [(LEFT, 30, rover.turn_units_for_yaw(math.pi / 2))]
    twin = Twin(load_ground("loose", rover).rover(rover), dt_s=0.01)
    return play(twin, steps).final_pose.yaw_deg


def test_rover_gate_check_plays_on_the_twin(twin_file: Path, field: Path, tmp_path: Path) -> None:
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(_quarter_turn_plan()))
    yaws = {}
    for name, extra in (("nominal", []), ("twin", ["--twin", str(twin_file)])):
        check = rover_cli(
            "gate", "check", str(plan), "--map", str(field), "--start", "20,20,0", "--json", *extra
        )
        assert check.returncode in (0, 1), check.stderr
        yaws[name] = json.loads(check.stdout)["final_pose"]["yaw_deg"]
    truth = _true_quarter_turn_deg()
    assert abs(yaws["twin"] - truth) < 0.5
    assert abs(yaws["nominal"] - truth) > 10.0
    both = rover_cli(
        "gate", "check", str(plan), "--twin", str(twin_file), "--rover", str(twin_file)
    )
    assert both.returncode == 2 and "not both" in both.stderr


def test_rover_gate_serves_the_twin(twin_file: Path, field: Path) -> None:
    from firmware_proto.model.pose import Pose
    from planner.plan.gate_client import GateClient
    from tests.child import Child

    args = ["gate", "--port", "0", "--pool", "thread", "--workers", "1", "--map", str(field)]
    args += ["--twin", str(twin_file)]
    gate = Child(args, dict(os.environ))
    try:
        url = gate.wait_for("GATE ").split()[1]
        with GateClient(url) as client:
            verdict = client.validate(
                _quarter_turn_plan(), map_name="field", start=Pose(20.0, 20.0, 0.0)
            )
        assert abs(verdict.final_pose.yaw_deg - _true_quarter_turn_deg()) < 0.5
        assert any("calibrated on field" in line for line in gate.errors)
    finally:
        gate.stop()


def _record(tmp_path: Path, steps: list[tuple[int, int, int]], name: str) -> Path:
    rover = load_rover()
    path = tmp_path / f"{name}.mcap"
    record_messages(
        path,
        drive_lockstep(rover, field_map(), load_ground("dusty", rover), steps, seed=1).messages,
    )
    return path


def test_a_recording_without_turns_is_refused(tmp_path: Path, field: Path) -> None:
    rec = _record(tmp_path, [(FWD, 20 + 8 * i, 23000) for i in range(6)], "straight")
    out = tmp_path / "twin.toml"
    done = rover_cli("calibrate", str(rec), "--map", str(field), "-o", str(out))
    assert done.returncode == 3
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot identify mu_lateral" in lines[0]
    assert not out.exists()
    with pytest.raises(UnidentifiableError) as caught:
        fit_ground(observe_steps([read_recording(rec)], load_rover()), load_rover(), None)
    assert caught.value.parameter == "mu_lateral"


def test_a_short_recording_is_refused(tmp_path: Path, field: Path) -> None:
    rec = _record(tmp_path, [(LEFT, 30, 8000), (FWD, 40, 23000), (RIGHT, 30, 8000)], "short")
    done = rover_cli("calibrate", str(rec), "--map", str(field))
    assert done.returncode == 3
    assert "too short to fit: 3 steps" in done.stderr


def test_what_is_not_a_recording_is_refused(tmp_path: Path, rover: RoverDescription) -> None:
    bogus = tmp_path / "x.mcap"
    bogus.write_bytes(b"not an mcap file")
    done = rover_cli("calibrate", str(bogus), str(tmp_path / "missing.mcap"))
    assert done.returncode == 2
    assert "not a readable MCAP file" in done.stderr
    with pytest.raises(RecordingError, match="no step could be measured"):
        fit_ground(observe_steps([], rover), rover, None)


def test_a_region_driven_on_is_fitted(
    rover: RoverDescription, lab: WorldMap, tmp_path: Path
) -> None:
    # On the lab map, turns and straights outside the sandbox, then into it, turns in
    # it, and back out; the sandbox is softer than the map says.
    quarter = rover.turn_units_for_yaw(math.pi / 2)
    steps = [
        (RIGHT, 30, quarter),
        (LEFT, 25, quarter),
        (FWD, 40, 23000),
        (FWD, 30, 23000),
        (LEFT, 30, quarter),
        (RIGHT, 20, quarter),
        (2, 40, 23000),
        (LEFT, 30, quarter // 2),
        (RIGHT, 45, quarter // 2),
        (2, 30, 11500),
    ]
    truth = load_ground("loose", rover).with_values(**{"region.sandbox": 0.35})
    path = tmp_path / "sandbox.mcap"
    mission = drive_lockstep(rover, lab, truth, steps, start=Pose2D(1.1, 3.2, math.pi / 2), seed=4)
    record_messages(path, mission.messages)
    observed = observe_steps([read_recording(path)], rover)
    assert len(observed.observations) == len(steps)
    calibration, _ = fit_ground(observed, rover, lab, posterior=False)
    assert "region.sandbox" in calibration.parameters
    assert calibration.value("region.sandbox") == pytest.approx(0.35, rel=0.3)


def test_a_region_not_driven_on_keeps_the_maps_scale(
    loose_recording: Path, rover: RoverDescription
) -> None:
    doc = json.loads(field_map().to_json())
    doc["traction_regions"] = [
        {"id": "far", "polygon": [[0.5, 0.5], [2.0, 0.5], [2.0, 2.0], [0.5, 2.0]], "mu_scale": 0.6}
    ]
    world = WorldMap.from_dict(doc)
    observed = observe_steps([read_recording(loose_recording)], rover)
    # Which regions are fitted is decided before the solver runs: a small budget of its
    # own (the fit's quality is test_the_fit_finds_the_ground_the_gate_did_not_know's).
    calibration, _ = fit_ground(observed, rover, world, max_evaluations=8, posterior=False)
    assert "region.far" not in calibration.parameters
    assert calibration.fixed_regions == ("far",)
    assert calibration.ground.region_scale("far") == 0.6


def test_loading_a_twin_needs_no_scipy() -> None:
    # The gate and the rover load twin files; only rover calibrate needs the extra.
    code = (
        "import sys, emulator.twinfile, emulator.calibration, gate.cli_gate\n"
        "print('scipy' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.strip() == "False"

"""Calibration from a mission recorded by the real stack: ``rover emulate`` on a ground
the gate does not know (a process, over a pty), ``rover bridge`` and ``rover link``
(processes, real ROS 2 over rclpy), the executor and the MCAP recorder in this process,
as ``rover go --record`` runs them; then ``rover calibrate`` on the file.

Four times faster than real time (the emulator's speed factor, the link's delay and the
executor's timeouts scaled alike), so about 25 s.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bridge.ros.rosport import open_port
from emulator.ground import load_ground
from emulator.playback import measure_turn_efficiency
from firmware_proto.model.plan import Plan
from firmware_proto.model.rover import load_rover
from firmware_proto.runtime.stall import describe_stalls, read_stalls
from planner.ground.executor import ExecutorConfig, PlanExecutor
from planner.record.mcaprec import McapRecorder
from tests.child import Child

# serial: a mission across four processes; alone, no other worker's load can starve the
# link past the controller's watchdog (as for the demo tests).
pytestmark = [pytest.mark.rclpy, pytest.mark.slow, pytest.mark.serial, pytest.mark.timeout(300)]

SPEED = 4.0
RTT_S = 3.0
"""The link's round trip, mission seconds (the rover rests this long between steps)."""


def _plan() -> Plan:
    rover = load_rover()
    quarter = rover.turn_units_for_yaw(math.pi / 2)
    steps = [
        ("LEFT", 30, quarter),
        ("FWD", 40, 13800),
        ("RIGHT", 45, quarter),
        ("FWD", 60, 18400),
        ("RIGHT", 20, quarter),
        ("FWD", 25, 18400),
        ("LEFT", 35, rover.turn_units_for_yaw(math.radians(135))),
        ("REV", 40, 11500),
        ("RIGHT", 30, quarter // 2),
        ("FWD", 50, 9200),
    ]
    return Plan.from_dict(
        {
            "goal": {"x": 2.4, "y": 2.5, "yaw_deg": 0.0},
            "commands": [{"command": c, "speed": s, "distance": d} for c, s, d in steps],
        }
    )


def test_a_real_run_on_an_unknown_ground_calibrates_the_twin(tmp_path: Path) -> None:
    rover = load_rover()
    # Every process logs its stalls here: a link fault then says who stalled.
    stalls = tmp_path / "stalls.jsonl"
    env = dict(os.environ, ROVER_STALL_LOG=str(stalls))
    link = tmp_path / "rover-motor"
    recording = tmp_path / "real.mcap"
    children: list[Child] = []
    try:
        args = ["emulate", "--serial", "--link", str(link), "--map", "lab", "--ground", "loose"]
        args += ["--speed-factor", f"{SPEED:g}", "--seed", "3"]
        emulator = Child(args, env)
        children.append(emulator)
        emulator.wait_for("DEVICE ")
        children.append(Child(["bridge", "--device", str(link)], env))
        children[-1].wait_for("BRIDGE ")
        children.append(Child(["link", "--rtt", f"{RTT_S / SPEED:g}", "--seed", "3"], env))
        children[-1].wait_for("LINK ")
        with (
            McapRecorder(recording) as recorder,
            open_port("rclpy", namespace="ground", node_name="rover_executor") as port,
        ):
            port.add_tap(recorder.tap)
            config = ExecutorConfig(link_rtt_s=RTT_S / SPEED, time_scale=SPEED, drift_control=False)
            executor = PlanExecutor(port, rover, config)
            try:
                assert executor.wait_for_rover(30.0), "no subscriber for the steps"
                # The rover's pose crossed the link: the rover is up and at rest.
                assert executor.settled_pose(30.0) is not None, "the rover never reported"
                result = executor.execute(_plan())
            finally:
                executor.close()
        assert result.completed, (
            result.reason,
            result.trace[-10:],
            [line for child in children for line in child.errors[-5:]],
            describe_stalls(read_stalls(stalls), 0.1),
        )
        assert any("GROUND loose" in line for line in emulator.errors)
    finally:
        for child in reversed(children):
            child.stop()

    twin = tmp_path / "twin.toml"
    command = [sys.executable, "-m", "firmware_proto.cli", "calibrate", str(recording)]
    command += ["--map", "lab", "--speed-factor", f"{SPEED:g}", "-o", str(twin), "--json"]
    done = subprocess.run(
        command,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["steps"] >= 8, report  # of 10: a rest disturbed by load may cost one
    truth = measure_turn_efficiency(
        load_ground("loose", rover).rover(rover),
        distance=rover.turn_units_for_yaw(math.pi / 2),
    )
    assert report["turn_efficiency"] == pytest.approx(truth, abs=0.02)
    before, after = report["residuals_before"], report["residuals_after"]
    assert before["yaw_deg"] > 3.0
    assert after["yaw_deg"] < before["yaw_deg"] / 5.0
    assert load_rover(twin).traction.turn_efficiency == pytest.approx(
        report["turn_efficiency"], abs=1e-4
    )

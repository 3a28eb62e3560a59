"""``rover demo`` and ``rover go`` as a user runs them: real processes, real ROS 2 (rclpy,
Fast DDS) in the private network namespace, real HTTP, real pty."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.model.worldmap import MAPS_DIR
from firmware_proto.runtime import stall
from tests.child import Child

pytestmark = pytest.mark.rclpy


def _demo(tmp_path: Path, firmware: str) -> subprocess.CompletedProcess[str]:
    picture = tmp_path / "demo.png"
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "demo",
            "--speed",
            "4",
            "--picture",
            str(picture),
            "--firmware",
            firmware,
        ],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
        cwd=tmp_path,
    )


@pytest.mark.serial
@pytest.mark.timeout(300)
@pytest.mark.parametrize("firmware", ["python", pytest.param("c", marks=pytest.mark.firmware)])
def test_rover_demo_plans_detours_stops_on_drift_replans_and_arrives(
    tmp_path: Path, firmware: str
) -> None:
    out = _demo(tmp_path, firmware)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    text = out.stdout
    assert "collision at step" in text and "(dogleg): approved" in text  # around the table
    assert "SCHEDULING slip:left" in text
    assert "drift STOP:" in text and "detection to STOP" in text
    # run on board (the default): the rover's guard stopped it, and the demo says how
    # far and how long it went on, from the rover's own stamped odom_ground
    assert "run on board as plan" in text and "(stopped on board)" in text
    assert "drift stop 1 (on board, the rover's own guard), from odom_ground:" in text
    assert "re-plan 1:" in text
    assert "REACHED" in text
    assert "ROS 2 middleware: rmw_fastrtps_cpp (rclpy 7." in text
    assert (tmp_path / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _go(
    url: str, picture: Path, *args: str, timeout_s: float = 60.0
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "go",
            "--map",
            "lab",
            "--gate",
            url,
            "--rtt",
            "0.1",
            "--picture",
            str(picture),
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
        env=dict(os.environ),
    )


def test_rover_go_refuses_bad_goals_and_options_cleanly(
    tmp_path: Path, gate_process_url: str
) -> None:
    picture = tmp_path / "m.png"
    for args, status, complaint in (
        (["--goal", "3.9,3.0,0"], 1, "obstacle 'table'"),  # checked before waiting for the rover
        (["--goal", "9.5,3.0,0"], 1, "outside map 'lab'"),
        (["--goal", "nowhere"], 1, "has no goal named 'nowhere' (its goals: behind_table, "),
        (["--goal", "nan,1,0"], 2, "not finite"),
        (["--goal", "1,2"], 2, "X,Y,YAW_DEG"),
        (["--goal", "2,3,0", "--start", "1,inf,0"], 2, "not finite"),
        (["--goal", "2,3,0", "--drift-linear", "0"], 2, "--drift-linear: must be finite and > 0"),
        (["--goal", "2,3,0", "--drift-angular", "nan"], 2, "--drift-angular"),
        (["--goal", "2,3,0", "--drift-samples", "1.5"], 2, "--drift-samples"),
        (["--goal", "2,3,0", "--view", "--view-host", "0.0.0.0"], 1, "without a token"),
    ):
        out = _go(gate_process_url, picture, *args)
        assert out.returncode == status, (args, out.stdout + out.stderr)
        assert "Traceback" not in out.stderr, out.stderr
        # One error line (a usage error comes after the usage synopsis).
        last = out.stderr.strip().splitlines()[-1]
        assert last.startswith("rover go: error: ") and complaint in last, (args, out.stderr)
        assert out.stderr.count("error:") == 1, out.stderr
    assert not picture.exists()


def test_rover_go_plan_refuses_bad_files_and_sends_no_rejected_plan(
    tmp_path: Path, gate_process_url: str
) -> None:
    picture = tmp_path / "m.png"
    into_the_table = tmp_path / "table.json"
    drive: dict[str, object] = {"command": "FWD", "speed": 40, "distance": 11500}
    plan = {"goal": {"x": 3.5, "y": 3.0, "yaw_deg": 0}, "commands": [drive]}
    into_the_table.write_text(json.dumps(plan))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**plan, "commands": [{"command": "FLY", "speed": 1}]}))
    for args, status, complaint in (
        (["--plan", str(tmp_path / "none.json")], 1, "cannot read it"),
        (["--plan", str(bad)], 1, "not a valid plan: /commands/0"),
        (["--plan", str(into_the_table), "--goal", "2,3,0"], 2, "not allowed with argument"),
        (["--plan", str(into_the_table), "--start", "9.5,3,0"], 1, "outside map 'lab'"),
        (["--plan", str(into_the_table), "--start", "1.2,3,0", "--move-and-wait"], 1, "as given"),
    ):
        out = _go(gate_process_url, picture, *args)
        assert out.returncode == status, (args, out.stdout + out.stderr)
        last = out.stderr.strip().splitlines()[-1]
        assert last.startswith("rover go: error: ") and complaint in last, (args, out.stderr)
    # Rejected by the gate (it runs into the table from 3.0, 3.0): nothing is sent, and
    # the rover is not even waited for (no bridge runs here).
    out = _go(gate_process_url, picture, "--plan", str(into_the_table), "--start", "3.0,3.0,0")
    assert out.returncode == 1, out.stdout + out.stderr
    assert "REJECTED: the plan was rejected with collision at step 0" in out.stdout
    assert "'table'" in out.stdout and "published" not in out.stdout
    assert "Traceback" not in out.stderr


def test_rover_go_without_a_reporting_rover_sends_nothing(
    tmp_path: Path, gate_process_url: str
) -> None:
    """No bridge, no link: no pose comes, and without --start nothing is assumed."""
    out = _go(gate_process_url, tmp_path / "m.png", "--goal", "2.7,3.0,0", "--pose-wait", "2")
    assert out.returncode == 1, out.stdout + out.stderr
    assert "the rover reported no pose" in out.stderr and "--start" in out.stderr
    assert "Traceback" not in out.stderr
    assert "step 1/" not in out.stdout


def test_rover_go_move_and_wait_plans_without_an_unreachable_gate_from_a_map_file(
    tmp_path: Path,
) -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    common = ["--move-and-wait", "--goal", "2.7,3.0,0", "--start", "1.2,3.0,0"]
    out = _go(url, tmp_path / "m.png", *common)  # --map lab: a name only the gate knows
    assert out.returncode == 1, out.stdout + out.stderr
    assert "is not answering" in out.stderr and "--map FILE.json" in out.stderr
    lab = MAPS_DIR / "lab.json"
    out = _go(url, tmp_path / "m.png", *common, "--map", str(lab), "--time-scale", "4")
    # No rover here either: the first command times out, and the rover is sent STOP.
    assert out.returncode == 1, out.stdout + out.stderr
    assert "the route is planned by the heuristic planner alone and NOT validated" in out.stdout
    assert "NOT REACHED (increment 1/" in out.stdout and "got no 'completed' in time" in out.stdout
    assert "Traceback" not in out.stderr


def _status(port: int) -> dict[str, Any]:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(b"status\n")
        answer = json.loads(sock.makefile().readline())
    assert answer["ok"], answer
    status: dict[str, Any] = answer["status"]
    return status


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_rover_go_interrupted_mid_step_stops_the_rover_and_says_cancelled(
    tmp_path: Path, gate_process_url: str, sig: signal.Signals
) -> None:
    # The uplink token through the environment (rover onboard checks, rover go signs).
    env = {**os.environ, "ROVER_UPLINK_TOKEN": "interrupted-go-token"}
    device = tmp_path / "rover-motor"
    children: list[Child] = []
    try:
        emulator = Child(
            [
                "emulate",
                "--serial",
                "--link",
                str(device),
                "--map",
                "lab",
                "--seed",
                "1",
                "--speed-factor",
                "4",
                "--control-port",
                "0",
            ],
            env,
        )
        children.append(emulator)
        control = int(emulator.wait_for("CONTROL ").rsplit(":", 1)[1])
        children.append(Child(["bridge", "--device", str(device)], env))
        children[-1].wait_for("BRIDGE ")
        # The rover's sequencer beside the bridge: rover go runs its plan on board.
        children.append(Child(["onboard", "--time-scale", "4"], env))
        children[-1].wait_for("ONBOARD ")
        children.append(Child(["link", "--rtt", "0.1", "--seed", "1"], env))
        children[-1].wait_for("LINK ")
        go = Child(
            [
                "go",
                "--goal",
                "1.2,1.5,-90",  # turn right (about 1.7 s wall), then south
                "--map",
                "lab",
                "--gate",
                gate_process_url,
                "--rtt",
                "0.1",
                "--time-scale",
                "4",
                "--picture",
                str(tmp_path / "m.png"),
            ],
            env,
        )
        children.append(go)
        line = go.wait_for("start (")  # the rover's own pose, the lab's start
        x, y, _ = (float(v) for v in line.split("start (", 1)[1].split(" deg")[0].split(","))
        assert abs(x - 1.2) < 0.05 and abs(y - 3.0) < 0.05, line
        go.wait_for(" running, ETA ")  # progress during a step
        # It is driving: the wheels ramp up from rest at the step's start, so the speed is
        # waited for (one sample taken right after the line once read zero).
        deadline = time.monotonic() + 10.0
        while not any(abs(v) > 0.01 for v in _status(control)["wheel_mps"]):
            assert time.monotonic() < deadline, _status(control)
            time.sleep(0.02)
        go.proc.send_signal(sig)
        assert go.wait(60) == 128 + sig, go.errors
        go.wait_for("NOT REACHED (cancelled by the operator)", timeout_s=0)
        assert not any("Traceback" in line for line in go.errors), go.errors
        # Its last word is the cancellation (its stall monitor may still log a stall of its
        # end, on a busy machine: a log record, not something it says).
        said = [line for line in go.errors if f" {stall.logger.name}: " not in line]
        assert said[-1] == "rover go: cancelled by the operator; the rover was sent STOP", said
        deadline = time.monotonic() + 10
        while _status(control)["wheel_mps"] != [0.0, 0.0]:
            assert time.monotonic() < deadline, "the rover did not come to rest"
            time.sleep(0.05)
        assert _status(control)["stop_latched"]
    finally:
        for child in reversed(children):
            child.stop()

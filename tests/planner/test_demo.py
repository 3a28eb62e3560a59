"""``rover demo`` and ``rover go`` as a user runs them: real processes, real DDS on
loopback (private network namespace), real HTTP, real pty."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bridge.rosport import loopback_config

pytestmark = pytest.mark.dds


def test_rover_demo_plans_detours_stops_on_drift_replans_and_arrives(tmp_path: Path) -> None:
    picture = tmp_path / "demo.png"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "demo",
            "--speed",
            "4",
            "--picture",
            str(picture),
        ],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    text = out.stdout
    assert "collision at step" in text and "-> dogleg" in text  # the gate caught the table
    assert "INJECTING slip:left" in text
    assert "drift STOP:" in text and "detection to STOP" in text
    assert "re-plan 1:" in text
    assert "REACHED" in text
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rover_go_refuses_a_goal_inside_an_obstacle_cleanly(
    tmp_path: Path, gate_process_url: str
) -> None:
    url = gate_process_url
    env = {**os.environ, "CYCLONEDDS_URI": loopback_config()}
    for goal, complaint in (
        ("3.9,3.0,0", "obstacle"),
        ("nan,1,0", "not finite"),
        ("1,2", "X,Y,YAW_DEG"),
    ):
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "firmware_proto.cli",
                "go",
                "--goal",
                goal,
                "--start",
                "1.2,3.0,0",
                "--map",
                "lab",
                "--gate",
                url,
                "--rtt",
                "0.1",
                "--picture",
                str(tmp_path / "m.png"),
            ],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
            env=env,
        )
        assert out.returncode == 1, out.stdout + out.stderr
        assert complaint in out.stderr and "Traceback" not in out.stderr

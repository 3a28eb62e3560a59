"""``rover demo --controller pil:TARGET``: the whole mission (gate, bridge over the
emulated UART, link, ground station) against the ATmega2560 image under simavr with the
twin as its plant, and the nRF51 image under qemu with its in-image plant: around the
table, a drift STOP on slip, a re-plan, the goal. Real
ROS 2 (marker ``rclpy``), one whole mission (marker ``serial``), in real time (the PIL
controller runs at 1x only). Mostly waiting (about 45 s of wall, under half a core), so
the test command runs it beside its other whole missions, not after them (marker
``beside``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from .pil_helpers import require_target

pytestmark = pytest.mark.rclpy


@pytest.mark.serial
@pytest.mark.beside
@pytest.mark.timeout(400)
@pytest.mark.parametrize("target", ["atmega2560", "microbit"])
def test_rover_demo_on_the_image_stops_on_drift_and_reaches_its_goal(
    target: str, tmp_path: Path
) -> None:
    """The bridge's mission over the emulated UART: with the twin as the ATmega2560's
    plant, or the nRF51's in-image kinematic plant (slip through its hooks)."""
    require_target(target)
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "demo",
            "--controller",
            f"pil:{target}",
            # The link's round trip as the Python model's demo has it at --speed 4: the
            # image's loop runs at 1x only, the link need not (the 3 s round trip is
            # the browser's mission's, tests/planner/test_view_browser.py).
            "--rtt",
            "0.75",
            "--picture",
            str(tmp_path / "demo.png"),
            "--no-record",
        ],
        capture_output=True,
        text=True,
        timeout=360,
        check=False,
        cwd=tmp_path,
    )
    text = out.stdout
    assert out.returncode == 0, text[-3000:] + out.stderr[-3000:]
    assert f"starting emulator: rover pil --target {target}" in text
    assert "SCHEDULING slip:left" in text and "applied_s" not in text.split("SCHEDULING")[1][:200]
    assert "drift STOP:" in text and "re-plan 1:" in text, text[-3000:]
    assert "REACHED" in text


def test_a_pil_controller_refuses_another_speed() -> None:
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "stack",
            "up",
            "--controller",
            "pil:microbit",
            "--speed",
            "4",
            "--duration",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode != 0
    assert "runs in real time only" in out.stdout + out.stderr

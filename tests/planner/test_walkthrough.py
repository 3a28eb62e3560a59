"""The walkthrough of docs/commands.md, 'Missions against a stack', run exactly as
written: a stack up, two missions, a fault, ``rover status`` saying why, ``rover
clear-stop``, a third mission. Real processes, real ROS 2 in the private network
namespace; the stack at ``--speed 4`` (a whole-mission test: marker ``serial``)."""

from __future__ import annotations

import json
import os
import re
import shlex
from pathlib import Path

import pytest

from tests.child import Child, run_rover

pytestmark = [pytest.mark.rclpy, pytest.mark.serial, pytest.mark.timeout(300)]

ROOT = Path(__file__).resolve().parents[2]


def _walkthrough_commands() -> list[str]:
    text = (ROOT / "docs" / "commands.md").read_text()
    section = text.split("## Missions against a stack: a walkthrough", 1)[1]
    blocks = re.findall(r"```\n(.*?)```", section, flags=re.S)
    return [line for block in blocks[:2] for line in block.splitlines() if line.strip()]


def test_the_walkthrough_two_missions_a_fault_status_clear_stop_and_a_third(
    tmp_path: Path, one_stack: None
) -> None:
    steps = _walkthrough_commands()
    assert steps == [
        "rover stack up",
        'eval "$(rover stack env)"',
        "rover go --goal behind_table",
        "rover go --goal by_the_pillar",
        "rover stack inject encoder-dropout:left",
        "rover status",
        "rover stack inject clear:encoder-dropout:left",
        "rover clear-stop",
        "rover go --goal by_the_pillar",
    ], "the walkthrough of docs/commands.md changed: change this test with it"
    env = dict(os.environ)  # the run's stack directory (tests/conftest.py)
    env.pop("ROS_DOMAIN_ID", None)  # the stack picks its own
    stack = Child(["stack", "up", "--speed", "4"], env)
    try:
        stack.wait_for("STACK UP domain ", timeout_s=120)
        assert any(
            line.startswith("health: rover status") and "READY" in line for line in stack.lines
        )
        # eval "$(rover stack env)"
        exported = run_rover("stack", "env", env=env)
        assert exported.returncode == 0, exported.stderr
        line = exported.stdout.strip()
        assert line.startswith("export ")
        shell = {k: v for k, v in (item.split("=", 1) for item in shlex.split(line)[1:])}
        assert shell["ROS_DOMAIN_ID"] == stack.wait_for("STACK UP domain ").split()[-1]
        assert shell["ROVER_LINK_RTT"] == "0.75" and shell["ROVER_TIME_SCALE"] == "4"
        user = {**env, **shell}
        picture = ["--picture", str(tmp_path / "mission.png")]

        first = run_rover("go", "--goal", "behind_table", *picture, env=user)
        assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-2000:]
        assert "REACHED" in first.stdout and "NOT REACHED" not in first.stdout
        assert "fell back to odom" not in first.stdout + first.stderr  # no false alarm

        second = Child(["go", "--goal", "by_the_pillar", *picture], user)
        try:
            second.wait_for(" running, ETA ", timeout_s=60)  # it drives
            injected = run_rover("stack", "inject", "encoder-dropout:left", env=user)
            assert injected.returncode == 0, injected.stderr
            assert injected.stdout.startswith("injected encoder-dropout:left")
            assert second.wait(120) == 1
        finally:
            second.stop()
        ended = next(x for x in second.lines if "NOT REACHED" in x)
        assert re.search(r"NOT REACHED \(step \d+/\d+: fault:encoder", ended), ended

        status = run_rover("status", env=user)
        assert status.returncode == 3, status.stdout + status.stderr  # held
        text = status.stdout
        assert "HELD: steps are refused" in text
        assert "FAULT" in text and "faults      ENCODER" in text
        assert "latched by a fault (ENCODER)" in text
        assert "fault:encoder" in text.split("statuses", 1)[1].splitlines()[0]
        as_json = json.loads(run_rover("status", "--json", env=user).stdout)
        assert as_json["faults"] == ["ENCODER"] and "fault" in as_json["latch"]

        fixed = run_rover("stack", "inject", "clear:encoder-dropout:left", env=user)
        assert fixed.returncode == 0, fixed.stderr
        cleared = run_rover("clear-stop", env=user)
        assert cleared.returncode == 0, cleared.stdout + cleared.stderr
        assert cleared.stdout.startswith("released: the latch is off (it was held by fault")

        third = run_rover("go", "--goal", "by_the_pillar", *picture, env=user)
        assert third.returncode == 0, third.stdout[-2000:] + third.stderr[-2000:]
        assert "REACHED" in third.stdout and "NOT REACHED" not in third.stdout
        assert run_rover("status", env=user).returncode == 0  # ready for a fourth
    finally:
        stack.proc.send_signal(2)
        assert stack.wait(60) == 0, stack.errors[-10:]
    assert stack.lines[-1] == "rover stack: down"

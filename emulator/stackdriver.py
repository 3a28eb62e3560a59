"""The driver of ``rover calibrate --drive`` on a real stack: the ground station's
commands, as an operator runs them.

Each round of a campaign (:mod:`emulator.campaign`) is one plan driven with ``rover go
--plan FILE --record FILE.mcap`` against the stack (gate, step-by-step executor, drift
control); the pose before the first round is ``rover echo odom_ground`` averaged over
:data:`POSE_SAMPLES`, after a round the rest its recording ends with. The emulator
package never imports the ground station (docs/architecture.md): it runs its commands,
each bounded by a timeout. docs/twin.md, "A designed calibration".
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from emulator.campaign import Driven
from emulator.errors import CalibrationError
from emulator.twin import Pose2D
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = ["DRIFT_LINEAR_M", "POSE_SAMPLES", "StackDriver"]

logger = logging.getLogger(__name__)

POSE_SAMPLES = 10
"""POSE samples averaged for the rover's pose before the first round."""
DRIFT_LINEAR_M = 0.5
"""Drift control's position limit for a calibration plan, m: the design's room, as the gate's
twin does not know this ground yet; the heading is unlimited (its error is what is measured)."""
_SCALE_ENV = "ROVER_TIME_SCALE"
_NAMES = {int(c): c.name for c in Command}


class StackDriver:
    """Drives a stack with ``rover go --plan`` (module docstring).

    Args:
        rover: the rover description (step durations, for the commands' timeouts).
        map_name: the map the stack's gate validates on.
        gate: the gate's URL (``None``: ``$ROVER_GATE_URL``).
        domain: the ROS 2 domain (``None``: ``$ROS_DOMAIN_ID``).
        time_scale: mission seconds per wall second (``None``: ``$ROVER_TIME_SCALE``,
            else 1).
        rtt_s: the link's round trip, wall s (``None``: ``rover go``'s default).
        env: the environment of the commands (default this process's).

    Raises:
        ValueError: ``time_scale`` not > 0.
    """

    def __init__(
        self,
        rover: RoverDescription,
        map_name: str,
        *,
        gate: str | None = None,
        domain: int | None = None,
        time_scale: float | None = None,
        rtt_s: float | None = None,
        env: dict[str, str] | None = None,
    ) -> None:
        self.env = dict(os.environ if env is None else env)
        scale = time_scale if time_scale is not None else float(self.env.get(_SCALE_ENV) or 1.0)
        if not (math.isfinite(scale) and scale > 0.0):
            raise ValueError(f"time_scale must be > 0, got {scale}")
        self.speed_factor = scale
        self.rover = rover
        self.map_name = map_name
        common: list[str] = []
        if domain is not None:
            common += ["--domain", str(domain)]
        self._common = common
        go = ["--map", map_name, "--time-scale", f"{scale:g}"]
        if gate is not None:
            go += ["--gate", gate]
        if rtt_s is not None:
            go += ["--rtt", f"{rtt_s:g}"]
        self._go = go + common
        self._rtt_s = rtt_s if rtt_s is not None else float(self.env.get("ROVER_LINK_RTT") or 3.0)
        self._step_by_step: bool | None = None

    def _executor(self) -> list[str]:
        """``--step-by-step`` where ``rover go`` has it: a calibration measures each step
        at rest, and only that executor rests between steps."""
        if self._step_by_step is None:
            done = self._rover(["go", "--help"], 60.0)
            self._step_by_step = "--step-by-step" in done.stdout
        return ["--step-by-step"] if self._step_by_step else []

    def _rover(self, args: list[str], timeout_s: float) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "firmware_proto.cli", *args]
        logger.info("running %s", " ".join(command))
        try:
            return subprocess.run(
                command,
                capture_output=True,
                text=True,
                timeout=timeout_s,
                env=self.env,
                check=False,
            )
        except subprocess.TimeoutExpired as exc:
            raise CalibrationError(
                f"rover {args[0]} did not finish within {timeout_s:.0f} s"
            ) from exc

    def pose(self) -> Pose2D:
        """The rover's pose: ``rover echo odom_ground`` averaged.

        Raises:
            CalibrationError: the rover reports no pose.
        """
        wait_s = self._rtt_s + 30.0
        echo = ["echo", "odom_ground", "--count", str(POSE_SAMPLES), "--json"]
        done = self._rover([*echo, "--timeout", f"{wait_s:g}", *self._common], wait_s + 30.0)
        poses = []
        for line in done.stdout.splitlines():
            if line.startswith("{"):
                msg: dict[str, Any] = json.loads(line)
                p = msg["pose"]["pose"]
                q = p["orientation"]
                yaw = 2.0 * math.atan2(float(q["z"]), float(q["w"]))
                poses.append((float(p["position"]["x"]), float(p["position"]["y"]), yaw))
        if done.returncode != 0 or not poses:
            tail = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise CalibrationError(f"the rover reports no pose on odom_ground: {tail}")
        x = sum(p[0] for p in poses) / len(poses)
        y = sum(p[1] for p in poses) / len(poses)
        yaw = math.atan2(sum(math.sin(p[2]) for p in poses), sum(math.cos(p[2]) for p in poses))
        return Pose2D(x, y, yaw)

    def drive(self, steps: Sequence[tuple[int, int, int]], *, goal: Pose2D, path: Path) -> Driven:
        """``rover go --plan`` on the plan of ``steps`` ending at ``goal``, recorded to
        ``path`` (plan and picture beside it, ``.json`` and ``.png``), the goal tolerances
        at their widest (the gate's twin does not know this ground yet).

        Raises:
            CalibrationError: ``rover go`` failed otherwise than by a rejection or a
                step that did not complete (the stack is not there, ...).
        """
        plan = {
            "goal": {
                "x": round(goal.x_m, 6),
                "y": round(goal.y_m, 6),
                "yaw_deg": round(math.degrees(goal.yaw_rad), 6),
            },
            "commands": [{"command": _NAMES[c], "speed": s, "distance": d} for c, s, d in steps],
        }
        plan_path = path.with_suffix(".json")
        plan_path.write_text(json.dumps(plan, indent=1) + "\n", encoding="utf-8")
        nominal = sum(self.rover.step_duration_s(s, d) for _c, s, d in steps)
        timeout = 2.0 * nominal / self.speed_factor + self._rtt_s * (len(steps) + 4) + 120.0
        args = ["go", "--plan", str(plan_path), "--record", str(path), *self._go]
        args += self._executor()
        args += ["--pos-tol", "10", "--yaw-tol", "180", "--replan", "0"]
        args += ["--drift-linear", f"{DRIFT_LINEAR_M:g}", "--drift-angular", "180"]
        args += ["--picture", str(path.with_suffix(".png"))]
        done = self._rover(args, timeout)
        out = done.stdout
        if "REJECTED:" in out:
            line = next(x for x in out.splitlines() if "REJECTED:" in x)
            reason = line.split("REJECTED:", 1)[1].strip()
            found = re.search(r" at step (\d+):", reason)
            return Driven(False, None, reason, int(found.group(1)) if found else None)
        if not path.exists():
            tail = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise CalibrationError(f"rover go --plan failed (exit {done.returncode}): {tail}")
        if done.returncode == 0:
            return Driven(True, path)
        reason = next((x for x in out.splitlines() if "NOT REACHED" in x), out[-200:])
        return Driven(True, path, reason.strip())

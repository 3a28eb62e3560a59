"""``rover go``: plan, validate, repair and execute a mission; the operator's command.

Also the ``rover_executor`` console script for ``ros2 run`` (:func:`main`).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["add_arguments", "main", "parse_pose", "register", "run"]


def parse_pose(text: str) -> Any:
    """``X,Y,YAW_DEG`` -> :class:`planner.geometry.Pose`.

    Raises:
        ValueError: not three finite numbers.
    """
    import math

    from planner.geometry import Pose

    parts = text.split(",")
    try:
        x, y, yaw = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"expected X,Y,YAW_DEG (three numbers), got {text!r}") from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError(f"pose {text!r} is not finite")
    return Pose(x, y, yaw)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``rover go`` and ``rover_executor``."""
    p.add_argument(
        "--goal", required=True, metavar="X,Y,YAW", help="goal pose: metres, metres, degrees"
    )
    p.add_argument(
        "--start",
        metavar="X,Y,YAW",
        help="start pose (default: the rover's reported pose, else the map's start)",
    )
    p.add_argument("--map", default=None, help="map to validate on (default: the gate's)")
    p.add_argument(
        "--gate",
        default=None,
        metavar="URL",
        help="gate URL (default $ROVER_GATE_URL or http://127.0.0.1:8080)",
    )
    p.add_argument("--token", default=None, help="gate bearer token (default $ROVER_GATE_TOKEN)")
    p.add_argument(
        "--ros-backend",
        choices=("dds", "rclpy", "inprocess"),
        default="dds",
        help="ROS port backend",
    )
    p.add_argument(
        "--namespace", default="ground", help="namespace of the ground-side topics (default ground)"
    )
    p.add_argument(
        "--dds-config",
        metavar="loopback|FILE|XML",
        help="Cyclone DDS config (default $CYCLONEDDS_URI)",
    )
    p.add_argument(
        "--rtt",
        type=float,
        default=3.0,
        help="link round trip, s, for timeouts and alignment (default 3)",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="twin seconds per wall second (an emulator sped up)",
    )
    p.add_argument(
        "--pose-source",
        choices=("odom_ground", "odom"),
        default="odom_ground",
        help="pose drift control compares (default: the ground-seeing odom_ground)",
    )
    p.add_argument("--no-drift", action="store_true", help="do not stop on drift")
    p.add_argument(
        "--replan",
        type=int,
        default=1,
        help="re-plans after drift STOPs (default 1; 0 stops there)",
    )
    p.add_argument(
        "--move-and-wait",
        action="store_true",
        help="no gate prediction: short commands, each confirmed through the round trip (baseline)",
    )
    p.add_argument(
        "--picture",
        type=Path,
        default=Path("mission.png"),
        help="PNG of predicted vs actual (default mission.png)",
    )


def register(subparsers: Any) -> None:
    """Add ``rover go``."""
    p = subparsers.add_parser(
        "go",
        help="plan, validate, repair and execute a mission over ROS 2",
        description=(
            "Plan a mission to --goal, validate it on the gate (repairing rejected plans, at "
            "most 4 attempts per leg), then execute it step by step over ROS 2 with drift "
            "control, showing progress, and write a picture of the predicted against the actual "
            "trajectory. Exit 0 when the goal is reached, 1 otherwise."
        ),
        epilog=(
            "example: rover go --goal 6.2,3.0,0 --map lab --gate http://127.0.0.1:8080 "
            "--dds-config loopback"
        ),
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run one mission; returns the exit status."""
    from bridge.rosport import loopback_config, open_port
    from firmware_proto.rover import load_rover
    from planner.executor import ExecutorConfig, PlanExecutor, Progress
    from planner.gate_client import GateClient
    from planner.mission import MissionRunner, MoveAndWait
    from planner.orchestrator import PlannerOrchestrator
    from planner.picture import picture_of, save
    from planner.planner import HeuristicLowLevelPlanner

    goal = parse_pose(args.goal)
    start = parse_pose(args.start) if args.start else None
    if args.rtt < 0 or args.time_scale <= 0:
        raise ValueError("--rtt must be >= 0 and --time-scale > 0")
    rover = load_rover()
    options: dict[str, Any] = {}
    if args.ros_backend == "dds" and args.dds_config:
        options["config"] = loopback_config() if args.dds_config == "loopback" else args.dds_config
    t0 = time.monotonic()

    def say(line: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f} s] {line}", flush=True)

    def progress(p: Progress) -> None:
        say(p.line(args.time_scale))

    with (
        GateClient(args.gate, token=args.token) as gate,
        open_port(
            args.ros_backend, namespace=args.namespace, node_name="rover_executor", **options
        ) as port,
    ):
        world = gate.get_map(args.map)
        orchestrator = PlannerOrchestrator(
            HeuristicLowLevelPlanner(rover, world=world), gate, map_name=args.map, world=world
        )
        config = ExecutorConfig(
            link_rtt_s=args.rtt,
            time_scale=args.time_scale,
            pose_source=args.pose_source,
            drift_control=not args.no_drift,
        )
        executor = PlanExecutor(port, rover, config)
        try:
            if start is None:
                start = executor.settled_pose(args.rtt + 2.0) or world.start
                say(f"start ({start.x:.2f}, {start.y:.2f}, {start.yaw_deg:.0f} deg)")
            runner = MissionRunner(
                orchestrator, executor, replans=args.replan, on_progress=progress, on_event=say
            )
            if args.move_and_wait:
                mission = orchestrator.plan_mission(goal, start=start)
                if not mission.approved:
                    raise RuntimeError(f"no route to follow: {mission.reason}")
                report = MoveAndWait(executor, time_scale=args.time_scale).drive(
                    goal, start, mission.plans
                )
            else:
                report = runner.run(goal, start=start)
        finally:
            executor.close()
    print(report.summary(args.time_scale))
    outcome = "reached" if report.reached else "not reached"
    picture = picture_of(report, world, f"rover go -> ({goal.x:.1f}, {goal.y:.1f}): {outcome}")
    print(f"picture: {save(picture, args.picture)}")
    return 0 if report.reached else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_executor`` for ``ros2 run`` and launch files: the options of ``rover go``,
    then optionally ``--ros-args`` (its ``--params-file`` section for the node and
    ``-p name:=value`` stand for the long options: ``map`` -> ``--map``)."""
    from firmware_proto.cli_rosargs import parse_args_with_ros_args

    parser = argparse.ArgumentParser(
        prog="rover_executor", description="Plan, validate and execute a mission."
    )
    add_arguments(parser)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)-7s %(name)s: %(message)s"
    )
    args = parse_args_with_ros_args(
        parser, list(sys.argv[1:] if argv is None else argv), "rover_executor"
    )
    try:
        return run(args)
    except Exception as exc:  # one clean line for the operator, whatever the package
        print(f"rover_executor: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

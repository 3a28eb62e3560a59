"""``rover go``: plan, validate, repair and execute a mission; the operator's command.

Also the ``rover_executor`` console script for ``ros2 run`` (:func:`main`).
"""

from __future__ import annotations

import argparse
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime
from planner.plan.cli_confidence import add_confidence_arguments, confidence_options
from planner.stack.stackenv import (
    RTT_ENV,
    SCALE_ENV,
    TWIN_ENV,
    add_domain_argument,
    env_default,
)
from planner.view.cli_view import add_view_arguments

if TYPE_CHECKING:
    from planner.plan.gate_client import GateOptions

__all__ = [
    "PoseArgumentError",
    "add_arguments",
    "main",
    "parse_goal",
    "parse_pose",
    "register",
    "resolve_goal",
    "run",
    "start_noise",
]

POSE_WAIT_MARGIN_S = 10.0
"""Without ``--start``, s past the round trip the rover has to report its pose (``--pose-wait``)."""

RECORD_REST_S = 1.5
"""With ``--record``, recording goes on until a pose stamped this long (mission s) after the last
status: the rest after the last step, which ``rover calibrate`` measures (docs/twin.md)."""


class PoseArgumentError(ValueError, argparse.ArgumentTypeError):
    """A pose on the command line is not three finite numbers (argparse reports it as a
    usage error; elsewhere it is a ``ValueError``)."""


def parse_pose(text: str) -> Any:
    """``X,Y,YAW_DEG`` -> :class:`firmware_proto.model.pose.Pose` (metres, metres, degrees); an
    ``argparse`` type (:class:`PoseArgumentError`, a ``ValueError``: not three finite numbers)."""
    import math

    from firmware_proto.model.pose import Pose

    parts = text.split(",")
    try:
        x, y, yaw = (float(p) for p in parts)
    except ValueError:
        raise PoseArgumentError(f"expected X,Y,YAW_DEG (three numbers), got {text!r}") from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise PoseArgumentError(f"pose {text!r} is not finite")
    return Pose(x, y, yaw)


def parse_goal(text: str) -> Any:
    """``--goal``: a pose ``X,Y,YAW_DEG`` (:func:`parse_pose`), or the name of one of the
    map's goals (a word without commas: ``behind_table``), resolved once the map is
    known (:func:`resolve_goal`); :class:`PoseArgumentError` (a ``ValueError``) for neither."""
    name = text.strip()
    if "," not in name and name.replace("_", "").replace("-", "").isalnum():
        return name
    return parse_pose(text)


def resolve_goal(goal: Any, world: Any) -> Any:
    """The pose of ``goal``: itself if a pose, else the map's goal of that name
    (``ValueError``: there is none; the message lists the map's goals)."""
    if not isinstance(goal, str):
        return goal
    for named in world.goals:
        if named.name == goal:
            return named.pose
    known = ", ".join(g.name for g in world.goals) or "none"
    raise ValueError(
        f"map {world.name!r} has no goal named {goal!r} (its goals: {known}); or give X,Y,YAW_DEG"
    )


def _number(text: str, *, positive: bool, integer: bool = False) -> float:
    import math

    try:
        value = int(text) if integer else float(text)
    except ValueError:
        kind = "an integer" if integer else "a number"
        raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise argparse.ArgumentTypeError(
            f"must be finite and {'> 0' if positive else '>= 0'}, got {text!r}"
        )
    return value


def _positive(text: str) -> float:
    return _number(text, positive=True)


def _non_negative(text: str) -> float:
    return _number(text, positive=False)


def _positive_int(text: str) -> int:
    return int(_number(text, positive=True, integer=True))


def _non_negative_int(text: str) -> int:
    return int(_number(text, positive=False, integer=True))


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``rover go`` and ``rover_executor``."""
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--goal",
        type=parse_goal,
        metavar="X,Y,YAW|NAME",
        help="goal pose (metres, metres, degrees), or the name of one of the map's goals "
        "(the lab map: behind_table, ...; an unknown name lists them)",
    )
    what.add_argument(
        "--plan",
        type=Path,
        metavar="FILE",
        help="drive this plan (Listing 1 JSON) instead of planning one: validated on the "
        "gate once as it is (no repair: a rejected plan is not sent), then executed as "
        "any approved plan, with drift control (no re-plan after a drift STOP)",
    )
    p.add_argument(
        "--start",
        type=parse_pose,
        metavar="X,Y,YAW",
        help=(
            "start pose (default: the pose the rover reports on odom_ground; if it reports "
            "none, nothing is sent)"
        ),
    )
    p.add_argument(
        "--pose-wait",
        type=_positive,
        default=None,
        metavar="S",
        help=(
            "without --start, how long to wait for the rover to report its pose, s (default: "
            f"the round trip + {POSE_WAIT_MARGIN_S:g})"
        ),
    )
    p.add_argument(
        "--map",
        default=None,
        help=(
            "map to validate on (default: the gate's); with --move-and-wait and the gate "
            "unreachable, a map file (JSON) to plan on"
        ),
    )
    p.add_argument(
        "--gate",
        default=None,
        metavar="URL",
        help="gate URL (default $ROVER_GATE_URL or http://127.0.0.1:8080)",
    )
    p.add_argument(
        "--token-file",
        default=None,
        metavar="PATH",
        help="gate bearer token, read from this file (default $ROVER_GATE_TOKEN)",
    )
    p.add_argument("--token", default=None, help=argparse.SUPPRESS)  # refused: ps shows it
    p.add_argument(
        "--ros-backend",
        choices=("rclpy", "inprocess"),
        default="rclpy",
        help="ROS port backend: rclpy (ROS 2, the default) or inprocess (tests only)",
    )
    p.add_argument(
        "--namespace", default="ground", help="namespace of the ground-side topics (default ground)"
    )
    p.add_argument(
        "--rtt",
        type=_non_negative,
        default=env_default(RTT_ENV, 3.0),
        help=f"link round trip, wall s, for timeouts and alignment (default ${RTT_ENV}, which "
        "rover stack up exports, else 3)",
    )
    p.add_argument(
        "--time-scale",
        type=_positive,
        default=env_default(SCALE_ENV, 1.0),
        help=f"twin seconds per wall second (an emulator sped up; default ${SCALE_ENV}, else 1)",
    )
    p.add_argument(
        "--pose-source",
        choices=("auto", "odom_ground", "odom"),
        default="auto",
        help=(
            "pose drift control compares: auto (default) uses the ground-seeing odom_ground "
            "while it is fresh and falls back to odom (warning) when it goes silent"
        ),
    )
    p.add_argument(
        "--pose-stale",
        type=_positive,
        default=0.5,
        metavar="S",
        help=(
            "with --pose-source auto, odom_ground silent this long (s, by the topics' "
            "stamps: an odom this much newer than the last odom_ground) -> odom (default "
            "0.5); no pose at all for the round trip plus twice this (at least 1 s) -> STOP"
        ),
    )
    p.add_argument(
        "--pos-tol",
        type=_positive,
        default=None,
        metavar="M",
        help="the gate's accepted final distance to the goal, m (default: the gate's)",
    )
    p.add_argument(
        "--yaw-tol",
        type=_positive,
        default=None,
        metavar="DEG",
        help="the gate's accepted final yaw error, degrees (default: the gate's)",
    )
    p.add_argument(
        "--drift-linear",
        type=_positive,
        default=0.25,
        metavar="M",
        help="drift STOP above this position error, m (default 0.25)",
    )
    p.add_argument(
        "--drift-angular",
        type=_positive,
        default=12.0,
        metavar="DEG",
        help="drift STOP above this heading error, degrees (default 12)",
    )
    p.add_argument(
        "--drift-samples",
        type=_positive_int,
        default=3,
        metavar="N",
        help="consecutive samples over a threshold before drift STOP (default 3)",
    )
    p.add_argument(
        "--no-drift",
        action="store_true",
        help="no drift control: no drift STOP, and no STOP when drift control hears no pose",
    )
    p.add_argument(
        "--replan",
        type=_non_negative_int,
        default=1,
        help="re-plans after drift STOPs (default 1; 0 stops there)",
    )
    p.add_argument(
        "--rover",
        metavar="TOML",
        default=os.environ.get(TWIN_ENV) or None,
        help=(
            f"rover description the planner turns by (default ${TWIN_ENV}, which rover "
            "stack up --twin exports, else the packaged one); a twin file from rover "
            "calibrate brings the ground's turn efficiency"
        ),
    )
    p.add_argument(
        "--step-by-step",
        action="store_true",
        help=(
            "run approved plans with the thesis's step-by-step executor (each step "
            "published, then its 'completed' awaited through the round trip; drift control "
            "on the ground) instead of on board (the default: the plan is uplinked once, "
            "the rover runs it and its guard stops a drift there; docs/onboard.md)"
        ),
    )
    p.add_argument(
        "--move-and-wait",
        action="store_true",
        help=(
            "the thesis's baseline operator: take the gate-approved route (planned and "
            "validated as usual; if the gate is unreachable, planned by the heuristic "
            "planner alone on --map FILE, unvalidated), cut drives into 0.5 m commands and "
            "send them one at a time, each confirmed through the round trip plus 2 s to "
            "decide; no prediction, so no drift control and no re-plan"
        ),
    )
    p.add_argument(
        "--picture",
        type=Path,
        default=None,
        help="PNG of predicted vs actual (default mission-YYYYmmdd-HHMMSS.png here: a new "
        "file for each mission, never the last one's)",
    )
    add_confidence_arguments(p)
    add_view_arguments(p, record_default=None)
    add_runtime_arguments(p, 0)
    add_domain_argument(p)


def register(subparsers: Any) -> None:
    """Add ``rover go``."""
    p = subparsers.add_parser(
        "go",
        help="plan, validate, repair and execute a mission over ROS 2",
        description=(
            "Plan a mission to --goal, validate it on the gate (repairing rejected plans, at "
            "most 4 attempts per leg), then execute it step by step over ROS 2 with drift "
            "control, showing progress, and write a picture of the predicted against the actual "
            "trajectory. Needs a running stack: a gate, an emulator (or the rover), a bridge "
            "and a link relay ('rover stack up' starts them and prints the export line that "
            "points this command at them: ROS_DOMAIN_ID, ROVER_GATE_URL). --goal takes a pose "
            "or a goal's name on the map; --plan FILE drives a given plan instead (validated "
            "once, not repaired, not re-planned). The goal is checked against the map first; "
            "without "
            "--start the rover must report its pose. Ctrl-C or SIGTERM cancels: the rover is "
            "sent STOP (a second "
            "one interrupts at once, after sending STOP). Exit 0 when the goal is reached, 130 "
            "(143) when cancelled by SIGINT (SIGTERM), 1 otherwise, 2 for bad options. "
            "--record FILE.mcap records the mission as ROS 2 MCAP; --view serves the live "
            "view with a STOP button and prints its URL (docs/view.md)."
        ),
        epilog=(
            "examples:\n"
            "  rover stack up    # in another shell; then there:\n"
            '  eval "$(rover stack env)"\n'
            "  rover go --goal behind_table\n"
            "  rover go --goal 6.2,3.0,0 --map lab --gate http://127.0.0.1:8080 --domain 101\n"
            "  rover go --plan plan.json --record plan.mcap"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    p.set_defaults(func=run)


def _offline_map(name: str | None, exc: Exception) -> Any:
    """The map for move-and-wait without a gate: ``--map`` must name a map file (a bare
    name means the map the gate serves under it, which only the gate knows)."""
    from firmware_proto.model.worldmap import load_map

    if name is None or not Path(name).is_file():
        raise RuntimeError(
            f"{exc}; --move-and-wait can plan without the gate from a map file: --map FILE.json"
        ) from exc
    return load_map(Path(name))


def _wait_for_pose(executor: Any, timeout_s: float, cancel: threading.Event) -> Any:
    """The rover's reported map pose, waiting at most ``timeout_s`` (or until cancel)."""
    deadline = time.monotonic() + timeout_s
    while not cancel.is_set():
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        pose = executor.settled_pose(min(left, 0.5))
        if pose is not None:
            return pose
    return None


def start_noise(options: GateOptions, sigma: tuple[float, float] | None) -> GateOptions:
    """``options`` with the start's own 1-sigma errors, ``sigma`` (m per position axis,
    deg), as the rover stated them with the pose it reported: the gate draws its twins'
    starts with them (``start_sigma_m``, ``start_sigma_deg``; docs/gate.md) instead of a
    calibration's rests', which a single reading does not have. Unchanged when the rover
    stated none."""
    if sigma is None:
        return options
    return replace(options, start_sigma_m=sigma[0], start_sigma_deg=sigma[1])


def _rover_pose(executor: Any, args: argparse.Namespace, cancel: threading.Event) -> Any:
    """The pose the rover reports (map frame); ``None`` if cancelled meanwhile;
    ``RuntimeError`` when it reported none in time (or cannot: ``odom`` is not in the map
    frame)."""
    if args.pose_source == "odom":
        raise RuntimeError(
            "with --pose-source odom the rover's pose on the map is unknown (odom starts "
            "where the bridge started); give --start X,Y,YAW"
        )
    wait_s = args.pose_wait if args.pose_wait is not None else args.rtt + POSE_WAIT_MARGIN_S
    pose = _wait_for_pose(executor, wait_s, cancel)
    if pose is None and not cancel.is_set():
        raise RuntimeError(
            f"the rover reported no pose on {args.namespace}/odom_ground within {wait_s:g} s "
            "(is the bridge running, the link relaying?); nothing was sent; give --start "
            "X,Y,YAW to drive from a known pose"
        )
    return pose


def _read_plan(path: Path) -> Any:
    """The plan of ``--plan FILE`` (``ValueError``: the file cannot be read, or is not a
    valid plan; the message names the first violation's JSON pointer)."""
    from firmware_proto.errors import PlanError
    from firmware_proto.model.plan import Plan

    try:
        return Plan.from_json(path.read_bytes())
    except OSError as exc:
        raise ValueError(f"--plan {path}: cannot read it: {exc.strerror or exc}") from None
    except PlanError as exc:
        pointer, message = exc.violations[0]
        raise ValueError(f"--plan {path}: not a valid plan: {pointer or '/'}: {message}") from None


def _gate_token(args: argparse.Namespace) -> str | None:
    """The gate's token from ``--token-file``, else ``None`` (the client then reads
    ``ROVER_GATE_TOKEN``); ``ValueError`` for ``--token`` (``ps`` would show it) or a file
    that cannot be used."""
    from firmware_proto.http.tokenfile import read_token_file, refuse_token_argument

    if args.token is not None:
        raise refuse_token_argument("--token", "--token-file", "ROVER_GATE_TOKEN")
    return read_token_file(args.token_file, what="gate token") if args.token_file else None


def run(args: argparse.Namespace) -> int:
    """Run one mission; returns the exit status (0 reached, 128 + the signal number when
    cancelled by a signal, 1 otherwise)."""
    with ProcessRuntime(runtime_options(args, "go")):
        return _mission(args)


def _mission(args: argparse.Namespace) -> int:
    from bridge.ros.rosport import open_port
    from firmware_proto.model.pose import Pose
    from firmware_proto.model.rover import load_rover
    from firmware_proto.model.uplink import token_from_env
    from planner.errors import GateUnavailableError
    from planner.ground.executor import ExecutionProgress, ExecutorConfig, PlanExecutor
    from planner.ground.interrupt import CancelOnSignal
    from planner.ground.mission import MissionReport, MissionRunner, MoveAndWait
    from planner.ground.onboard import OnboardExecutor, UplinkOptions
    from planner.plan.gate_client import GateClient
    from planner.plan.orchestrator import PlannerOrchestrator
    from planner.plan.planner import HeuristicLowLevelPlanner, check_pose
    from planner.record.foxlive import FoxgloveLive
    from planner.record.mcaprec import McapRecorder, recording_unavailable
    from planner.record.picture import fresh_path, picture_of, save
    from planner.stack.stackenv import apply_domain
    from planner.stack.stallreport import stall_report
    from planner.view.cli_view import view_config
    from planner.view.live import LiveView

    if args.record and recording_unavailable():
        print(f"rover go: --record: {recording_unavailable()}", file=sys.stderr)
        return 2
    apply_domain(args)
    given = _read_plan(args.plan) if args.plan is not None else None
    goal = args.goal if given is None else given.goal
    view_cfg = view_config(args)
    start = args.start
    config = ExecutorConfig(
        link_rtt_s=args.rtt,
        time_scale=args.time_scale,
        pose_source=args.pose_source,
        pose_stale_s=args.pose_stale,
        drift_linear_m=args.drift_linear,
        drift_angular_deg=args.drift_angular,
        drift_persistence=args.drift_samples,
        drift_control=not args.no_drift,
        blind_margin_s=max(1.0, 2.0 * args.pose_stale),
    )
    rover = load_rover(getattr(args, "rover", None))
    t0 = time.monotonic()
    started = time.time()
    cancel = threading.Event()

    view: LiveView | None = None
    recorder: McapRecorder | None = None
    foxglove: FoxgloveLive | None = None
    running = threading.Event()
    hold_end = threading.Event()

    def say(line: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f} s] {line}", flush=True)
        if view is not None:
            view.hub.event(line)

    def progress(p: ExecutionProgress) -> None:
        if view is not None:
            view.hub.progress(p)
        say(p.line(args.time_scale))

    def view_stop() -> str:
        cancel.set()
        if running.is_set():
            say("STOP from the view: cancelling the mission (a running step ends with STOP)")
            return "sent: the running step ends with STOP, the mission is cancelled"
        say("STOP from the view: the mission is cancelled")
        return "the mission is cancelled; nothing more is sent"

    def view_clear(executor: Any) -> bool:
        if not running.is_set():
            raise RuntimeError("the mission has ended")
        say("clear-STOP from the view: releasing the latch")
        return bool(executor.clear_stop())

    def planned(mission: Any) -> None:
        if recorder is not None:
            recorder.planned(mission)
        if foxglove is not None:
            foxglove.planned(mission)
        if view is not None:
            view.hub.planned(mission)

    def on_signal(signum: int) -> None:
        hold_end.set()
        cancel.set()
        say(
            f"{signal.Signals(signum).name}: cancelling the mission (a running step ends with STOP)"
        )

    with GateClient(args.gate, token=_gate_token(args)) as gate:
        gated = True
        try:
            world = gate.get_map(args.map)
        except GateUnavailableError as exc:
            if not args.move_and_wait:
                raise
            world = _offline_map(args.map, exc)
            gated = False
        if given is None:
            goal = resolve_goal(goal, world)
        else:
            goal = Pose(given.goal.x, given.goal.y, given.goal.yaw_deg)
        planner = HeuristicLowLevelPlanner(rover, world=world)
        # Bad goals (and starts) end here, before anything waits for the rover.
        if given is None:
            planner.route(start or world.start, goal)
        elif start is not None:
            check_pose("start", start, world=world)
        with (
            open_port(
                args.ros_backend, namespace=args.namespace, node_name="rover_executor"
            ) as port,
            CancelOnSignal(on_signal) as signals,
        ):
            gate_options, max_p = confidence_options(args)
            gate_options = replace(gate_options, pos_tol_m=args.pos_tol, yaw_tol_deg=args.yaw_tol)
            orchestrator = PlannerOrchestrator(
                planner,
                gate,
                map_name=args.map,
                world=world,
                options=gate_options,
                max_collision_p=max_p,
            )
            executor = (
                PlanExecutor(port, rover, config)
                if args.step_by_step or args.move_and_wait
                else OnboardExecutor(
                    port,
                    rover,
                    config,
                    # The uplink's token, never the gate's (docs/onboard.md, "The uplink": Tokens).
                    UplinkOptions(token=token_from_env(os.environ)),
                )
            )
            if args.record:
                recorder = McapRecorder(args.record)
                recorder.attach(port)
                recorder.set_map(world, goal)
            if args.foxglove is not None:
                foxglove = FoxgloveLive(port=args.foxglove)
                port.add_tap(foxglove.tap)
                print(f"FOXGLOVE {foxglove.url}", flush=True)
            if view_cfg is not None:
                view = LiveView(
                    world,
                    view_cfg,
                    rtt_s=args.rtt,
                    time_scale=args.time_scale,
                    on_stop=view_stop,
                    on_clear=functools.partial(view_clear, executor),
                    drift_source=lambda: executor.latest_drift,
                )
                port.add_tap(view.hub.tap)
                print(f"VIEW {view.url}", flush=True)
                if view_cfg.wait_s > 0:
                    say(f"waiting up to {view_cfg.wait_s:g} s for a browser to open the view")
                    if view.hub.wait_for_client(view_cfg.wait_s):
                        say("view: a browser is watching")
            report: MissionReport | None = None
            try:
                if start is None:
                    start = _rover_pose(executor, args, cancel)
                    # The gate's twins start as far off as the rover said this pose may be.
                    orchestrator.options = start_noise(
                        orchestrator.options, executor.reported_sigma
                    )
                if cancel.is_set() or start is None:
                    print("rover go: cancelled; nothing was sent to the rover", file=sys.stderr)
                    return signals.exit_status
                say(f"start ({start.x:.2f}, {start.y:.2f}, {start.yaw_deg:.0f} deg)")
                if given is not None and args.move_and_wait:
                    raise ValueError("--plan drives the plan as given: not with --move-and-wait")
                if given is not None:
                    runner = MissionRunner(
                        orchestrator,
                        executor,
                        replans=0,
                        on_progress=progress,
                        on_event=say,
                        cancel=cancel,
                        on_planned=planned,
                    )
                    running.set()
                    try:
                        report = runner.run_plan(given, start=start)
                    finally:
                        running.clear()
                elif args.move_and_wait:
                    plannings: tuple[Any, ...] = ()
                    tp = time.monotonic()
                    if gated:
                        mission = orchestrator.plan_mission(goal, start=start)
                        planned(mission)
                        if not mission.approved:
                            raise RuntimeError(f"no route to follow: {mission.reason}")
                        plans = mission.plans
                        plannings = (mission,)
                    else:
                        say(
                            "WARNING: the gate is unreachable: the route is planned by the "
                            "heuristic planner alone and NOT validated"
                        )
                        plans = tuple(leg.plan for leg in planner.plan_mission(start, goal))
                    report = MoveAndWait(
                        executor, time_scale=args.time_scale, on_progress=progress, cancel=cancel
                    ).drive(
                        goal,
                        start,
                        plans,
                        plannings=plannings,
                        planning_s=time.monotonic() - tp,
                    )
                else:
                    runner = MissionRunner(
                        orchestrator,
                        executor,
                        replans=args.replan,
                        on_progress=progress,
                        on_event=say,
                        cancel=cancel,
                        on_planned=planned,
                    )
                    running.set()
                    try:
                        report = runner.run(goal, start=start)
                    finally:
                        running.clear()
            finally:
                if recorder is not None and report is not None and report.runs:
                    # The rest after the last step, for rover calibrate.
                    executor.settled_pose(after_s=RECORD_REST_S / args.time_scale)
                executor.close()
                if foxglove is not None:
                    foxglove.close()
                if recorder is not None:
                    recorder.close()
                    print(f"recording: {recorder.path} (rover decode {recorder.path})")
                if view is not None and sys.exc_info()[0] is not None:
                    view.close()  # else it serves the end of the mission until the end
    print(report.summary(args.time_scale))
    options = runtime_options(args, "go")
    for line in stall_report(
        report,
        since_wall_s=started,
        stall_log=options.stall_log,
        threshold_s=options.stall_threshold_s,
    ):
        print(line)
    if view is not None:
        view.hub.result(report.reached, report.summary(args.time_scale).splitlines()[0])
    outcome = "reached" if report.reached else "cancelled" if report.cancelled else "not reached"
    picture = picture_of(report, world, f"rover go -> ({goal.x:.1f}, {goal.y:.1f}): {outcome}")
    print(f"picture: {save(picture, args.picture or fresh_path('mission', Path(), started))}")
    status = 0 if report.reached else 1
    if report.cancelled:
        what = "the rover was sent STOP" if report.runs else "nothing was sent to the rover"
        print(f"rover go: cancelled by the operator; {what}", file=sys.stderr)
        status = signals.exit_status
    if view is not None:
        if view_cfg is not None and view_cfg.hold_s > 0:
            print(f"view: still at {view.url} for {view_cfg.hold_s:g} s", flush=True)
            with CancelOnSignal(lambda signum: hold_end.set()):
                hold_end.wait(view_cfg.hold_s)  # Ctrl-C ends it
        view.close()
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """``rover_executor`` for ``ros2 run`` and launch files: the options of ``rover go``,
    then optionally ``--ros-args`` (its ``--params-file`` section for the node and
    ``-p name:=value`` stand for the long options: ``map`` -> ``--map``)."""
    from firmware_proto.cli.program import ros_main

    parser = argparse.ArgumentParser(
        prog="rover_executor", description="Plan, validate and execute a mission."
    )
    add_arguments(parser)
    # A Ctrl-C that gets through (a second signal) finds the STOP already sent.
    return ros_main(parser, run, argv, with_rclpy=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``rover demo``: the whole stack on one machine, driving a mission (the README's main job)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from firmware_proto.cli.runtimeargs import add_runtime_arguments
from planner.plan.cli_confidence import add_confidence_arguments, confidence_options
from planner.stack.controllers import CONTROLLERS
from planner.stack.linkargs import add_link_arguments
from planner.view.cli_view import add_view_arguments

__all__ = ["DEMO_RECORDING", "register"]

DEMO_RECORDING = "demo.mcap"
"""Where the demo records its mission by default (with the ``record`` extra; else nowhere)."""


def register(subparsers: Any) -> None:
    """Add ``rover demo``."""
    p = subparsers.add_parser(
        "demo",
        help="the end-to-end demo: gate, emulator, bridge, 3 s link, planner and executor",
        description=(
            "Start the gate, the motor-controller emulator on a pty (lab map), the ROS 2 "
            "bridge and the Earth-Moon link relay (3 s round trip) as separate processes, "
            "talking real ROS 2 (rclpy) kept on this host; plan a mission behind the table (the "
            "direct plan collides, the orchestrator repairs it into a detour), drive it, inject "
            "slip on one leg so that drift control stops the rover, re-plan from the rover's "
            "reported pose and finish. Prints a summary and writes a picture of the predicted "
            "against the actual trajectory. About 80 s in real time (--speed 4: under one minute). "
            "Ctrl-C or SIGTERM cancels: the rover is sent STOP, the processes are stopped. "
            "The mission is recorded as ROS 2 MCAP (--record, default demo.mcap); --view "
            "serves the live view (the ghost against the rover, drift, a STOP button) and "
            "prints its URL (docs/view.md)."
        ),
    )
    add_link_arguments(p)
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="mission seconds per wall second: emulator and link run this much faster (default 1)",
    )
    p.add_argument("--no-slip", action="store_true", help="drive without injecting slip")
    p.add_argument(
        "--step-by-step",
        action="store_true",
        help="run the plans with the thesis's step-by-step executor and drift control on "
        "the ground, instead of on board (the default: uplinked once, run and guarded by "
        "the rover; docs/onboard.md)",
    )
    p.add_argument(
        "--seed", type=int, default=1, help="seed of sensor noise and the link (default 1)"
    )
    p.add_argument(
        "--picture", type=Path, default=Path("demo.png"), help="PNG to write (default demo.png)"
    )
    add_view_arguments(p, record_default=DEMO_RECORDING)
    p.add_argument(
        "--ground",
        metavar="NAME|FILE",
        help=(
            "the emulator drives on this ground, which the gate does not know (rover "
            "emulate --ground: loose, compacted, dusty or a file); expect drift STOPs"
        ),
    )
    p.add_argument(
        "--twin",
        metavar="FILE",
        help=(
            "a calibrated twin (rover calibrate): the gate plays plans on it and the "
            "planner turns by its turn efficiency"
        ),
    )
    p.add_argument(
        "--replan",
        type=int,
        default=None,
        metavar="N",
        help="re-plans after drift STOPs (default 1; 4 with --ground: a first day)",
    )
    p.add_argument(
        "--firmware",
        choices=("python", "c"),
        default="python",
        help="the emulator's controller: the Python model or the C firmware core (default python)",
    )
    p.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="emulator",
        help="the controller: the emulator (default; --firmware chooses its core), or the "
        "firmware image in an emulated MCU (rover pil: pil:microbit under qemu, "
        "pil:atmega2560 under simavr with the twin as its plant; real time only)",
    )
    p.add_argument(
        "--no-realtime",
        action="store_true",
        help="run the emulator and the bridge without real-time scheduling (by default they "
        "ask for it where permitted: docs/realtime.md)",
    )
    add_confidence_arguments(p)
    add_runtime_arguments(p, 0)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import signal
    import time

    from firmware_proto.cli.runtimeargs import runtime_options
    from firmware_proto.runtime import ProcessRuntime
    from planner.ground.interrupt import CancelOnSignal
    from planner.record.mcaprec import recording_unavailable
    from planner.stack.demo import Demo, DemoConfig
    from planner.stack.lines import say
    from planner.stack.stallreport import stall_report
    from planner.view.cli_view import view_config

    gate_options, max_p = confidence_options(args)
    record = None if args.no_record else Path(args.record)
    missing = recording_unavailable() if record is not None else ""
    if missing and args.record != DEMO_RECORDING:
        print(f"rover demo: --record: {missing}", file=sys.stderr)
        return 2
    if missing:
        print(f"not recording the mission: {missing}", flush=True)
        record = None
    config = DemoConfig(
        rtt_s=args.rtt,
        jitter_s=args.jitter,
        loss=args.loss,
        speed=args.speed,
        slip=None if args.no_slip else DemoConfig.slip,
        seed=args.seed,
        picture=args.picture,
        record=record,
        view=view_config(args),
        foxglove_port=args.foxglove,
        firmware=args.firmware,
        controller=args.controller,
        realtime=not args.no_realtime,
        ground=args.ground,
        twin=Path(args.twin) if args.twin else None,
        replans=(
            args.replan if args.replan is not None else (4 if args.ground else DemoConfig.replans)
        ),
        samples=gate_options.samples,
        max_collision_p=max_p,
        step_by_step=args.step_by_step,
    )
    started = time.time()
    with Demo(config, say=say) as demo:
        options = dataclasses.replace(runtime_options(args, "demo"), stall_log=demo.stall_log)
        runtime = ProcessRuntime(options)

        def on_signal(signum: int) -> None:
            if demo.holding:
                demo.end_hold()
                return
            if not demo.mission_running:
                raise KeyboardInterrupt  # nothing to stop yet: end the start-up now
            demo.cancel()
            demo.say(f"{signal.Signals(signum).name}: cancelling the mission; sending STOP")

        with runtime, CancelOnSignal(on_signal) as signals:
            result = demo.run()
            cancel_status = signals.exit_status  # a signal ending the hold is no cancel
            print()
            print(result.report.summary(config.speed))
            if result.timing is not None:
                print(result.timing.line())
            mode = (
                "step by step, drift control on the ground"
                if config.step_by_step
                else ("on board, the rover's own guard")
            )
            for i, (by_drift, by_path) in enumerate(result.physical, 1):
                # measured from the rover's own stamped odom_ground (docs/onboard.md)
                detected = by_drift.line(time_scale=config.speed, what="the drift was detected")
                print(f"drift stop {i} ({mode}), from odom_ground: {detected}; ")
                print(f"  {by_path.line(time_scale=config.speed)}")
            for line in stall_report(
                result.report,
                since_wall_s=started,
                stall_log=demo.stall_log,
                threshold_s=options.stall_threshold_s,
                logs=demo.logs,
            ):
                print(line)
            print(f"picture: {result.picture}")
            print(f"logs: {demo.logs} (each process's stderr; stalls.jsonl)")
            if result.recording is not None:
                print(f"recording: {result.recording} (rover decode {result.recording})")
            if config.view is not None and config.view.hold_s > 0:
                print(
                    f"view: still at {demo.view_url} for {config.view.hold_s:g} s (Ctrl-C ends it)",
                    flush=True,
                )
                demo.hold(config.view.hold_s)
    if result.report.cancelled:
        what = "the rover was sent STOP" if result.report.runs else "nothing was sent to the rover"
        print(f"rover demo: cancelled by the operator; {what}", file=sys.stderr)
        return cancel_status
    if config.slip and not result.drift_fired:
        print("note: the injected slip did not make drift control fire this time")
    return 0 if result.report.reached else 1

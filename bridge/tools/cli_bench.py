"""``rover bench stop``: the STOP bench test against a real controller or the emulator."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from firmware_proto.cli import values
from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime import ProcessRuntime
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY

__all__ = ["can_spec", "register"]


def can_spec(text: str) -> tuple[str, str]:
    """``INTERFACE:CHANNEL`` -> ``(interface, channel)``, an argparse type
    (:func:`firmware_proto.linkio.urls.parse_can_spec`)."""
    from firmware_proto.linkio.errors import LinkUrlError
    from firmware_proto.linkio.urls import parse_can_spec

    try:
        return parse_can_spec(text)
    except LinkUrlError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def register(subparsers: Any) -> None:
    """Add ``rover bench`` and ``rover bench stop``."""
    bench = subparsers.add_parser(
        "bench",
        help="bench tests of a real controller or the emulator (stop)",
        description="Bench tests against a real motor controller or the emulator.",
    )
    sub = bench.add_subparsers(dest="bench_command", metavar="TEST")
    sub.required = True
    p = sub.add_parser(
        "stop",
        help="measure STOP -> acknowledged / stopped / wheels at zero, under load",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "The STOP bench test (docs/bench.md). Per trial: fill the controller's motion "
            "queue, start moving, send STOP at a random (seeded) moment, and time STOP -> "
            "STOP_ACK, -> STOPPED (the controller reports rest) and -> the first "
            "WHEEL_SPEEDS at zero; then check that MOTION is refused STOP_LATCHED, that "
            "CLEAR_STOP releases the latch and that MOTION is accepted again (a "
            "zero-distance step). The link is loaded: the queue is full and telemetry runs "
            "at --telemetry-hz; on CAN a second sender floods the bus with lowest-priority "
            "frames. Prints p50/p95/p99/max per measure and writes stop_trials.csv, "
            "stop_trials.json and stop_hist.png into --out. Exit status 0 when every trial "
            "passed every check. THE ROVER MOVES: put it on blocks or give it 3 m."
        ),
        epilog=(
            "examples:\n"
            "  rover bench stop --serial /dev/rover-motor --trials 30 --out bench-out\n"
            "  rover bench stop --can socketcan:rovercan0 --node 1 --flood-can socketcan:can1\n"
            "  rover emulate --serial --link /tmp/rover-motor &  "
            "rover bench stop --serial /tmp/rover-motor\n"
            "note: python-can 'virtual' and SocketCAN 'vcan' have no arbitration; only a real\n"
            "bus with the flood sent from a second adapter makes STOP win arbitration."
        ),
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--serial", metavar="DEVICE", help="serial device or pyserial URL (/dev/rover-motor)"
    )
    where.add_argument(
        "--can",
        metavar="INTERFACE:CHANNEL",
        type=can_spec,
        help="python-can bus, e.g. socketcan:rovercan0 or virtual:rover",
    )
    p.add_argument(
        "--node", type=values.can_node, default=1, help="CAN node id of the controller (1)"
    )
    p.add_argument("--baud", type=values.baud, help="serial baud rate (default 115200)")
    p.add_argument("--trials", type=int, default=30, help="STOPs to measure (default 30)")
    p.add_argument("--seed", type=int, default=0, help="seed of the STOP moments (default 0)")
    p.add_argument(
        "--out",
        metavar="DIR",
        type=Path,
        help="where the CSV, JSON and PNG go (default bench-stop-YYYYmmdd-HHMMSS)",
    )
    p.add_argument(
        "--speed", type=int, default=60, help="MOTION speed units of the steps, 1..60 (60)"
    )
    p.add_argument(
        "--max-delay",
        type=float,
        default=0.5,
        metavar="SECONDS",
        help="STOP comes 0..SECONDS after motion starts (default 0.5)",
    )
    p.add_argument(
        "--telemetry-hz",
        type=int,
        default=100,
        help="telemetry rate set with SET_PARAM for the run; 0 leaves it (default 100)",
    )
    p.add_argument(
        "--flood-hz",
        type=float,
        default=2000.0,
        help="CAN: flood frames per second; 0 = back to back (real buses only) (2000)",
    )
    p.add_argument(
        "--flood-can",
        metavar="INTERFACE:CHANNEL",
        type=can_spec,
        help="CAN: send the flood on this bus (a second adapter on the same wire)",
    )
    p.add_argument(
        "--flood-id",
        type=lambda s: int(s, 0),
        metavar="ID",
        help="CAN: identifier to flood (default: PARAM_VALUE of another node, 0x63F)",
    )
    p.add_argument("--no-flood", action="store_true", help="CAN: do not flood the bus")
    p.add_argument(
        "--flood-malformed",
        action="store_true",
        help=(
            "CAN: flood malformed frames aimed at --node instead (wrong length, unknown "
            "id, extended id, RTR, error frame): the controller must ignore them"
        ),
    )
    p.add_argument(
        "--timeout", type=float, default=5.0, metavar="SECONDS", help="per answer (default 5)"
    )
    p.add_argument("--record", metavar="FILE", help="record the bench's link traffic")
    add_runtime_arguments(p, BRIDGE_PRIORITY)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    """As the bridge, the host here keeps time (its heartbeats feed the controller's
    watchdog): real-time scheduling where permitted (docs/realtime.md), for the trials
    only. The bench's modules are imported before (imports are CPU-bound: at real-time
    priority they hold a core from everything else), and the report (the table, the
    CSV, the JSON and the histogram's PNG: about a second of CPU) is written after."""
    import bridge.tools.benchreport  # noqa: F401 (and the bench it reports on)
    import firmware_proto.linkio.trafficio  # noqa: F401

    runtime = ProcessRuntime(runtime_options(args, "bench", BRIDGE_PRIORITY))
    with runtime:
        if runtime.realtime is not None and not runtime.realtime.granted:
            print(runtime.line(), file=sys.stderr, flush=True)
        return _bench(args, runtime)


def _bench(args: argparse.Namespace, runtime: ProcessRuntime) -> int:
    from bridge.tools.benchreport import format_table, write_reports
    from bridge.tools.stopbench import BenchConfig, FloodConfig, StopBench, TrialResult
    from firmware_proto.linkio.trafficio import open_recorder

    flood = None
    if args.can:
        interface, channel = args.can
        url = f"can://{interface}/{channel}?node={args.node}"
        if not args.no_flood:
            f_interface, f_channel = args.flood_can or args.can
            flood = FloodConfig(
                f_interface,
                f_channel,
                rate_hz=args.flood_hz,
                arbitration_id=args.flood_id,
                malformed=args.flood_malformed,
            )
            if args.flood_hz == 0 and f_interface == "virtual":
                raise ValueError("--flood-hz 0 on a virtual bus would flood memory; give a rate")
    else:
        url = args.serial if not args.baud else f"{args.serial}?baud={args.baud}"
    config = BenchConfig(
        url=url,
        trials=args.trials,
        seed=args.seed,
        speed=args.speed,
        max_delay_s=args.max_delay,
        telemetry_hz=args.telemetry_hz,
        timeout_s=args.timeout,
        flood=flood,
    )
    out = args.out or Path(time.strftime("bench-stop-%Y%m%d-%H%M%S"))
    recorder = (
        open_recorder(
            args.record,
            "can" if args.can else "serial",
            channel=args.can[1] if args.can else "",
            metadata={"role": "bench", "url": url},
        )
        if args.record
        else None
    )

    def progress(t: TrialResult) -> None:
        def ms(v: float | None) -> str:
            return f"{v:7.2f}" if v is not None else "      -"

        status = "ok" if t.ok else f"FAILED {t.error}".rstrip()
        print(
            f"trial {t.trial:3d}: ack {ms(t.ack_ms)} ms, stopped {ms(t.stopped_ms)} ms, "
            f"zero {ms(t.zero_ms)} ms  {status}",
            file=sys.stderr,
            flush=True,
        )

    try:
        with StopBench(config, recorder=recorder) as bench:
            run = bench.run(progress)
    finally:
        runtime.wind_down()  # the trials are over: the rest need not keep time
        if recorder is not None:
            recorder.close()
    print(format_table(run))
    paths = write_reports(run, out)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0 if run.passed == len(run.trials) else 1

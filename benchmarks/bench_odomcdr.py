"""Odometry as bytes: the bridge's packing and the onboard reading of ``nav_msgs/Odometry``
(bridge/ros/rosport/cdr.py, bridge/ros/odommsg.py) beside rclpy's own serialization of the message, in one run.

Run: ``python -m benchmarks.bench_odomcdr [--count N] [--repeat R] [--quick]``. Prints one
table, microseconds of CPU per message (``time.process_time``), the median and the worst
of ``R`` repeats of ``N`` messages each:

- *build + serialize (rclpy)*: what the bridge did per ``/odom`` before
  (``wheel_odometry`` builds the nested message, ``serialize_message`` converts it);
- *pack (odomcdr)*: ``wheel_odometry_cdr``, what it does now;
- *deserialize (rclpy)*: what a subscriber of the message pays to be handed it
  (``deserialize_message``, the conversion rclpy makes on a take);
- *read in place (odomcdr)*: ``read_odometry``, what ``rover onboard`` does now.

Needs rclpy (the ROS 2 message packages). The stack-level effect (an idle stack's CPU)
is docs/rosport.md, "Serialized messages".
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable

from bridge.link.odometry import OdometryEstimate
from bridge.ros.odommsg import wheel_odometry, wheel_odometry_cdr
from bridge.ros.rosport.cdr import read_odometry, stamp_parts
from bridge.ros.rosport.msgs import Odometry, stamp

COUNT = 20_000
REPEAT = 5


def per_message_us(run: Callable[[int], object], count: int, repeat: int) -> tuple[float, float]:
    """``(median, worst)`` CPU microseconds per call of ``run(i)`` over ``repeat`` runs of
    ``count`` calls."""
    runs = []
    for _ in range(repeat):
        t0 = time.process_time()
        for i in range(count):
            run(i)
        runs.append((time.process_time() - t0) / count * 1e6)
    return statistics.median(runs), max(runs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench_odomcdr", description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=COUNT, help=f"messages a run ({COUNT})")
    parser.add_argument("--repeat", type=int, default=REPEAT, help=f"runs a case ({REPEAT})")
    parser.add_argument("--quick", action="store_true", help="2,000 messages, 3 runs")
    args = parser.parse_args(argv)
    count, repeat = (2_000, 3) if args.quick else (args.count, args.repeat)
    if count < 1 or repeat < 1:
        parser.error("--count and --repeat must be at least 1")
    from rclpy.serialization import deserialize_message, serialize_message

    est = OdometryEstimate(1.25, -0.5, 0.3, 0.2, 0.05, 3.0, 1e-4, 2e-4, "imu")
    cdr = wheel_odometry_cdr(est, stamp_parts(1.8e9), "odom", "base_link")
    if deserialize_message(cdr, Odometry) != wheel_odometry(est, stamp(1.8e9), "odom", "base_link"):
        print("bench_odomcdr: the packed message does not read back as built", file=sys.stderr)
        return 1
    cases: list[tuple[str, Callable[[int], object]]] = [
        (
            "build + serialize (rclpy, before)",
            lambda i: serialize_message(wheel_odometry(est, stamp(1.8e9 + i), "odom", "base_link")),
        ),
        (
            "pack (odomcdr)",
            lambda i: wheel_odometry_cdr(est, stamp_parts(1.8e9 + i), "odom", "base_link"),
        ),
        ("deserialize (rclpy, before)", lambda i: deserialize_message(cdr, Odometry)),
        ("read in place (odomcdr)", lambda i: read_odometry(cdr)),
    ]
    print(f"nav_msgs/Odometry, {len(cdr)} bytes; {count:,} messages a run, {repeat} runs")
    print()
    print("| case | us/msg p50 | us/msg worst |")
    print("|---|---:|---:|")
    for name, run in cases:
        p50, worst = per_message_us(run, count, repeat)
        print(f"| {name} | {p50:.2f} | {worst:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

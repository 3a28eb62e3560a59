"""Discovery benchmark: how long a ROS 2 program that starts beside running ones waits
before its publisher matches them, with the project's Fast DDS profile
(``bridge/ros/rosport/fastdds_profile.xml``, a re-announcement every 0.5 s) beside Fast
DDS's default (every 3 s), measured in the same run; and what each costs idle.

Run it in a private network namespace with only loopback (as the tests run)::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_discovery'

For each profile: ``--running`` plain rclpy processes each hold a subscription on one
topic (a stack's parts, as it were); then ``--starts`` newcomers start one after another,
each a plain rclpy process that creates a publisher on that topic and times, on
CLOCK_MONOTONIC, how long until it counts every running subscription. Then the running
processes' CPU over ``--idle`` seconds of doing nothing (the announcements' cost).
Everything is real ROS 2 Jazzy (rclpy, rmw_fastrtps_cpp), discovery kept on this host
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, as ``rover stack up`` runs), each profile
on a ROS 2 domain of its own. ``--quick``: 2 running, 2 starts, 1 s idle (the smoke
test's).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import readline_within, summary, tree_cpu_s
from bridge.ros.rosport.discovery import PROFILE, PROFILE_ENVS

TOPIC = "bench_discovery"
MATCH_TIMEOUT_S = 20.0
CHILD_TIMEOUT_S = 60.0

_RUNNING = """
import sys, rclpy
from rclpy.node import Node
from std_msgs.msg import Bool
rclpy.init()
node = Node("running")
node.create_subscription(Bool, sys.argv[1], lambda m: None, 10)
print("up", flush=True)
sys.stdin.read()  # until the benchmark closes it
node.destroy_node()
rclpy.try_shutdown()
"""

_NEWCOMER = """
import sys, time, rclpy
from rclpy.node import Node
from std_msgs.msg import Bool
rclpy.init()
node = Node("newcomer")
pub = node.create_publisher(Bool, sys.argv[1], 10)
want, limit = int(sys.argv[2]), float(sys.argv[3])
t0 = time.monotonic()
while pub.get_subscription_count() < want and time.monotonic() - t0 < limit:
    time.sleep(0.002)
print(f"{time.monotonic() - t0:.6f} {pub.get_subscription_count()}", flush=True)
node.destroy_node()
rclpy.try_shutdown()
"""


def measure(
    env: dict[str, str], running: int, starts: int, idle_s: float
) -> tuple[list[float], float]:
    """``starts`` newcomers' match times, s, and the running processes' idle CPU, in
    fractions of a core, under ``env``."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _RUNNING, TOPIC],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(running)
    ]
    try:
        for proc in procs:
            assert proc.stdout is not None
            if readline_within(proc.stdout, CHILD_TIMEOUT_S, "a running process").strip() != "up":
                raise RuntimeError("a running process did not start")
        time.sleep(1.0)  # past their own start's announcements
        times = []
        for _ in range(starts):
            done = subprocess.run(
                [sys.executable, "-c", _NEWCOMER, TOPIC, str(running), str(MATCH_TIMEOUT_S)],
                env=env,
                capture_output=True,
                text=True,
                timeout=CHILD_TIMEOUT_S,
                check=True,
            )
            elapsed, matched = done.stdout.split()
            if int(matched) < running:
                raise RuntimeError(f"a newcomer matched {matched} of {running} in time")
            times.append(float(elapsed))
        before = sum(tree_cpu_s(p.pid) for p in procs)
        t0 = time.monotonic()
        time.sleep(idle_s)
        cores = (sum(tree_cpu_s(p.pid) for p in procs) - before) / (time.monotonic() - t0)
        return times, cores
    finally:
        for proc in procs:
            if proc.stdin is not None:
                proc.stdin.close()
        for proc in procs:
            try:
                proc.wait(timeout=CHILD_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=CHILD_TIMEOUT_S)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_discovery", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--running", type=int, default=6, help="running processes (6)")
    parser.add_argument("--starts", type=int, default=20, help="newcomers per profile (20)")
    parser.add_argument("--idle", type=float, default=10.0, help="idle CPU window, s (10)")
    parser.add_argument("--quick", action="store_true", help="2 running, 2 starts, 1 s idle")
    parser.add_argument("--domain", type=int, default=170, help="first ROS 2 domain (170)")
    args = parser.parse_args(argv)
    running, starts, idle_s = (2, 2, 1.0) if args.quick else (args.running, args.starts, args.idle)
    if running < 1 or starts < 1 or idle_s <= 0:
        parser.error("--running and --starts must be >= 1 and --idle > 0")
    base = {k: v for k, v in os.environ.items() if k not in PROFILE_ENVS}
    base["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    with tempfile.TemporaryDirectory() as tmp:
        # The peer: our profile with Fast DDS's default period written in (3 s).
        default = Path(tmp) / "default.xml"
        ours = PROFILE.read_text()
        written = ours.replace("<sec>0</sec>", "<sec>3</sec>").replace(
            "<nanosec>500000000</nanosec>", "<nanosec>0</nanosec>"
        )
        if written.count("<sec>3</sec>") != 1 or "500000000" in written:
            raise RuntimeError(f"{PROFILE}: its announcement period is not where it was")
        default.write_text(written)
        cases = [
            ("Fast DDS default (3 s)", default),
            ("our profile (0.5 s)", PROFILE),
        ]
        rows = []
        for index, (name, profile) in enumerate(cases):
            env = {**base, **dict.fromkeys(PROFILE_ENVS, str(profile))}
            env["ROS_DOMAIN_ID"] = str(args.domain + index)
            times, cores = measure(env, running, starts, idle_s)
            rows.append((name, summary(times), cores))
    print(
        f"## A newcomer's publisher matching {running} running subscriptions "
        f"({starts} starts each, rmw_fastrtps_cpp, discovery on this host)\n"
    )
    print("| profile | n | p50 ms | p99 ms | max ms | idle CPU, % of a core |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, s, cores in rows:
        print(
            f"| {name} | {int(s['n'])} | {s['p50']:.0f} | {s['p99']:.0f} | {s['max']:.0f} "
            f"| {100 * cores:.1f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""ROS port benchmark: message latency and sustained rate, ours beside plain rclpy.

Run it in a private network namespace with only loopback (as the tests run)::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_rosport'

Cases, three of them between two processes (the publisher here, the subscriber in a child
process), all real ROS 2 Jazzy (rclpy, rmw_fastrtps_cpp):

- ``rosport rclpy``: our ``rclpy`` backend on both sides (the port's default lane);
- ``rosport rclpy, STOP lane``: the same on the STOP lane (a node and wait set of its
  own, as the bridge's ``emergency_stop``);
- ``rosport rclpy-process`` and its STOP lane: the bridge's backend, the node in a child
  process of each side (docs/rosport.md);
- ``raw rclpy``: a plain rclpy node on each side with a ``SingleThreadedExecutor``, same
  QoS and topic: the peer, none of our code;
- ``rosport inprocess``: our in-process backend (one process, nothing serialised).

Latency is one way, from just before ``publish`` to the subscriber's callback, and
``call`` the time spent inside ``publish``, both on CLOCK_MONOTONIC; ``sub CPU us/msg`` is
the subscriber process's CPU time (every thread, the middleware's too) per message, where
that process holds the node (not for ``rclpy-process`` or in process); messages are paced
at 500/s (latency, not queueing). The sustained rate is messages/s with nothing lost:
acknowledged every 5th, at most 10 (the keep-last depth) unacknowledged.
"""

from __future__ import annotations

import argparse
import fcntl
import functools
import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bridge.ros.rosport import DEFAULT_LANE, STOP_LANE, open_port
from bridge.ros.rosport.msgs import Header, Int16MultiArray, Odometry, String

REPO = Path(__file__).resolve().parents[1]
LATENCY_COUNT = 2000
LATENCY_RATE_HZ = 500.0
RATE_COUNT = 20000
#: The publisher keeps at most this many messages unacknowledged (the keep-last depth).
WINDOW = 10
#: The subscriber acknowledges every ACK_EVERY-th message.
ACK_EVERY = 5
TOPIC = "/bench"
ACK_TOPIC = "/bench_ack"
CHILD_TIMEOUT_S = 120.0
#: How long the subscriber waits for stragglers after the sender has sent its last, s.
GRACE_S = 2.0

_SIOCGIFFLAGS = 0x8913
_IFF_UP = 0x1
_IFF_MULTICAST = 0x1000
NETNS_HELP = (
    "bench_rosport must run in a private network namespace with only loopback, e.g.:\n"
    "  unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on && "
    "exec .venv/bin/python -m benchmarks.bench_rosport'\n"
    "(DDS discovery multicasts; nothing may leave this machine.)"
)


def in_private_loopback_namespace() -> tuple[bool, str]:
    """True when this network namespace has only lo, up and multicast-capable.

    Asks the kernel for this namespace's interfaces (``/sys/class/net`` may show the
    host's: sysfs belongs to the namespace that mounted it).
    """
    interfaces = sorted(name for _, name in socket.if_nameindex())
    if interfaces != ["lo"]:
        return False, f"network interfaces present: {', '.join(interfaces)}"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        request = struct.pack("16sH14s", b"lo", 0, b"")
        flags = struct.unpack("16sH14s", fcntl.ioctl(sock.fileno(), _SIOCGIFFLAGS, request))[1]
    if not flags & _IFF_UP:
        return False, "lo is down"
    if not flags & _IFF_MULTICAST:
        return False, "lo has multicast off"
    return True, "only lo, up, multicast on"


# -- messages -------------------------------------------------------------------------

#: kind -> (type, message for seq, seq of a received message)
KINDS: dict[str, tuple[type[Any], Callable[[int], Any], Callable[[Any], int]]] = {
    "Int16MultiArray[3]": (
        Int16MultiArray,
        lambda seq: Int16MultiArray(data=[seq, 30, 23000]),
        lambda msg: int(msg.data[0]),
    ),
    "String": (
        String,
        lambda seq: String(data=f"accepted:{seq}"),
        lambda msg: int(msg.data.rsplit(":", 1)[1]),
    ),
    # The stack's busiest topic (/odom, 200/s at --speed 4): 700-odd bytes, covariances.
    "Odometry": (
        Odometry,
        lambda seq: Odometry(header=Header(frame_id=str(seq))),
        lambda msg: int(msg.header.frame_id),
    ),
}


# -- endpoints per case: a sender (publish + acks in) and a receiver (records + acks out)


class Link:
    """One side of one case: send or receive messages of one kind on TOPIC."""

    def send(self, seq: int) -> None:
        raise NotImplementedError

    def ack(self, count: int) -> None:
        raise NotImplementedError

    def wait_heard(self) -> bool:
        """Receiver: until its subscription hears a publisher and its acknowledgements
        reach a subscription (each end of a DDS match discovers the other on its own; a
        message sent before both did is lost)."""
        raise NotImplementedError

    def wait_acks_heard(self) -> bool:
        """Sender: until its subscription to the acknowledgements hears a publisher."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class RosportLink(Link):
    def __init__(
        self, backend: str, kind: str, role: str, on_message: Callable[[Any], None], lane: str
    ) -> None:
        msg_type, make, _ = KINDS[kind]
        options: dict[str, Any] = {"bus": "bench"} if backend == "inprocess" else {}
        self.port = open_port(backend, node_name=f"bench_{role}", **options)
        self._make = make
        if role == "sender":
            self._pub = self.port.publisher(TOPIC, msg_type)
            self._ack_sub = self.port.subscribe(ACK_TOPIC, Int16MultiArray, on_message)
            self._messages: list[Any] = []
        else:
            self._ack = self.port.publisher(ACK_TOPIC, Int16MultiArray)
            self._sub = self.port.subscribe(TOPIC, msg_type, on_message, lane=lane)

    def wait_heard(self) -> bool:
        return self._sub.wait_for_publishers(1, timeout_s=30.0) and (
            self._ack.wait_for_subscribers(1, timeout_s=30.0)
        )

    def wait_acks_heard(self) -> bool:
        return self._ack_sub.wait_for_publishers(1, timeout_s=30.0)

    def prepare(self, count: int) -> None:
        self._messages = [self._make(seq) for seq in range(count)]

    def wait_matched(self) -> bool:
        return self._pub.wait_for_subscribers(1, timeout_s=30.0)

    def send(self, seq: int) -> None:
        self._pub.publish(self._messages[seq])

    def ack(self, count: int) -> None:
        self._ack.publish(Int16MultiArray(data=[count]))

    def close(self) -> None:
        self.port.close()


def _within(timeout_s: float, done: Callable[[], bool]) -> bool:
    """Poll ``done`` every 10 ms until it holds (True) or ``timeout_s`` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


class RawLink(Link):
    """A plain rclpy node (none of our code): default QoS, a SingleThreadedExecutor
    spinning on a thread, as the ROS 2 tutorials write it."""

    def __init__(self, kind: str, role: str, on_message: Callable[[Any], None]) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        msg_type, self._make, _ = KINDS[kind]
        self._context = Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node(f"raw_{role}", context=self._context)
        if role == "sender":
            self._writer = self._node.create_publisher(msg_type, TOPIC, 10)
            self._ack_sub = self._node.create_subscription(
                Int16MultiArray, ACK_TOPIC, on_message, 10
            )
        else:
            self._writer = self._node.create_publisher(Int16MultiArray, ACK_TOPIC, 10)
            self._sub = self._node.create_subscription(msg_type, TOPIC, on_message, 10)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._stop = threading.Event()
        self._samples: list[Any] = []

        def spin() -> None:
            while not self._stop.is_set():
                self._executor.spin_once(timeout_sec=0.1)

        self._thread = threading.Thread(target=spin, name="raw-spin", daemon=True)
        self._thread.start()

    def prepare(self, count: int) -> None:
        self._samples = [self._make(seq) for seq in range(count)]

    def wait_matched(self) -> bool:
        return _within(30.0, lambda: self._writer.get_subscription_count() >= 1)

    def wait_heard(self) -> bool:
        return _within(30.0, lambda: self._sub.get_publisher_count() >= 1) and _within(
            30.0, lambda: self._writer.get_subscription_count() >= 1
        )

    def wait_acks_heard(self) -> bool:
        return _within(30.0, lambda: self._ack_sub.get_publisher_count() >= 1)

    def send(self, seq: int) -> None:
        self._writer.publish(self._samples[seq])

    def ack(self, count: int) -> None:
        self._writer.publish(Int16MultiArray(data=[count]))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self._executor.shutdown()
        self._node.destroy_node()
        self._context.try_shutdown()


def make_link(backend: str, kind: str, role: str, on_message: Callable[[Any], None]) -> Any:
    """``raw``, ``rclpy``, ``rclpy-process`` (each also ``-stop``: STOP lane), ``inprocess``."""
    if backend == "raw":
        return RawLink(kind, role, on_message)
    if backend.endswith("-stop"):
        return RosportLink(backend.removesuffix("-stop"), kind, role, on_message, STOP_LANE)
    return RosportLink(backend, kind, role, on_message, DEFAULT_LANE)


# -- the receiving side ---------------------------------------------------------------------


class Receiver:
    """Records each message's arrival; acknowledges every ACK_EVERY-th when asked to."""

    def __init__(self, backend: str, kind: str, count: int, acks: bool) -> None:
        self._seq_of = KINDS[kind][2]
        self._count = count
        self._acks = acks
        self.times: dict[int, int] = {}
        self.done = threading.Event()
        self.link = make_link(backend, kind, "receiver", self._record)

    def _record(self, msg: Any) -> None:
        self.times[self._seq_of(msg)] = time.monotonic_ns()
        got = len(self.times)
        if self._acks and (got % ACK_EVERY == 0 or got == self._count):
            self.link.ack(got)
        if got >= self._count:
            self.done.set()


def child(backend: str, kind: str, count: int, acks: bool) -> int:
    """The subscriber process: print ``ready``; on ``go`` (the sender's publisher exists)
    wait until the subscription hears it and print ``matched``; then record until every
    message came, or ``GRACE_S`` after the sender says ``end``; print the arrival times
    as JSON, with the CPU time this process used meanwhile (every thread: the port's and
    the middleware's; ``None`` for ``rclpy-process``, whose node is a process of its own)."""
    receiver = Receiver(backend, kind, count, acks)
    ended = threading.Event()
    cpu_s: float | None = None
    try:
        print("ready", flush=True)
        if sys.stdin.readline().strip() != "go":
            return 1
        print("matched" if receiver.link.wait_heard() else "unheard", flush=True)
        cpu0 = time.process_time()

        def wait_end() -> None:
            sys.stdin.readline()
            ended.set()

        threading.Thread(target=wait_end, daemon=True).start()
        deadline = time.monotonic() + CHILD_TIMEOUT_S
        while not receiver.done.wait(0.05) and time.monotonic() < deadline:
            if ended.is_set():
                receiver.done.wait(GRACE_S)  # stragglers; what is missing then was lost
                break
        if not backend.startswith("rclpy-process"):
            cpu_s = time.process_time() - cpu0
    finally:
        receiver.link.close()
    print(json.dumps({"times": receiver.times, "cpu_s": cpu_s}), flush=True)
    return 0


# -- the sending side -----------------------------------------------------------------------


class Sender:
    def __init__(self, backend: str, kind: str) -> None:
        self._acked = 0
        #: Nanoseconds each ``publish`` call took, by sequence number.
        self.calls: dict[int, int] = {}
        self._cond = threading.Condition()
        self.link = make_link(backend, kind, "sender", self._on_ack)

    def _on_ack(self, msg: Any) -> None:
        with self._cond:
            self._acked = max(self._acked, int(msg.data[0]))
            self._cond.notify_all()

    def _room(self, seq: int) -> bool:
        return seq - self._acked < WINDOW

    def run(self, count: int, rate_hz: float | None) -> dict[int, int]:
        """Send ``count``: paced at ``rate_hz``, or windowed by acks when None."""
        self.link.prepare(count)
        if not self.link.wait_matched():
            raise RuntimeError("the subscriber never matched")
        sent: dict[int, int] = {}
        period_ns = int(1e9 / rate_hz) if rate_hz else 0
        next_ns = time.monotonic_ns()
        for seq in range(count):
            if period_ns:
                next_ns += period_ns
                delay = next_ns - time.monotonic_ns()
                if delay > 0:
                    time.sleep(delay / 1e9)
            else:
                with self._cond:
                    if not self._cond.wait_for(functools.partial(self._room, seq), 10.0):
                        raise RuntimeError(f"no acknowledgement after message {seq}")
            sent[seq] = time.monotonic_ns()
            self.link.send(seq)
            self.calls[seq] = time.monotonic_ns() - sent[seq]
        return sent


def run_case(
    backend: str, kind: str, count: int, rate_hz: float | None
) -> tuple[dict[int, int], dict[int, int], dict[int, int], float | None]:
    """Send and receive one case; return send and arrival times, and the ``publish``
    calls' durations, by sequence number (ns), and the subscriber process's CPU seconds
    from the match to the last message (``None`` where the subscriber's node is not
    that process: in process, and ``rclpy-process``)."""
    acks = rate_hz is None
    if backend == "inprocess":
        receiver = Receiver(backend, kind, count, acks)
        sender = Sender(backend, kind)
        try:
            sent = sender.run(count, rate_hz)
            receiver.done.wait(30.0)
        finally:
            sender.link.close()
            receiver.link.close()
        return sent, receiver.times, sender.calls, None
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "benchmarks.bench_rosport",
            "--child", backend, kind, str(count), "acks" if acks else "noacks",
        ],
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdin is not None
        if proc.stdout.readline().strip() != "ready":
            raise RuntimeError(f"the {backend} subscriber did not start")
        sender = Sender(backend, kind)
        try:
            proc.stdin.write("go\n")
            proc.stdin.flush()
            if proc.stdout.readline().strip() != "matched":
                raise RuntimeError(f"the {backend} subscriber never heard the publisher")
            if not sender.link.wait_acks_heard():
                raise RuntimeError(f"the {backend} sender never heard the acknowledgements")
            sent = sender.run(count, rate_hz)
            proc.stdin.write("end\n")
            proc.stdin.flush()
            out, _ = proc.communicate(timeout=CHILD_TIMEOUT_S)
        finally:
            sender.link.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    report = json.loads(out.strip().splitlines()[-1])
    arrived = {int(k): v for k, v in report["times"].items()}
    cpu_s = report["cpu_s"]
    return sent, arrived, sender.calls, None if cpu_s is None else float(cpu_s)


# -- report ----------------------------------------------------------------------------------

CASES = (
    ("rosport rclpy (2 processes)", "rclpy"),
    ("rosport rclpy, STOP lane (2 proc.)", "rclpy-stop"),
    ("rosport rclpy-process (2 processes)", "rclpy-process"),
    ("rosport rclpy-process, STOP lane", "rclpy-process-stop"),
    ("raw rclpy (2 processes)", "raw"),
    ("rosport inprocess (1 process)", "inprocess"),
)


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--latency-count", type=int, default=LATENCY_COUNT)
    parser.add_argument("--rate-count", type=int, default=RATE_COUNT)
    parser.add_argument(
        "--kind",
        action="append",
        choices=list(KINDS),
        help="message kind to measure (repeatable; default: every one)",
    )
    args = parser.parse_args(argv)
    if max(args.rate_count, args.latency_count) > 32767:
        parser.error("counts must fit an int16 sequence number (<= 32767)")

    ok, why = in_private_loopback_namespace()
    if not ok:
        print(f"{NETNS_HELP}\nhere: {why}", file=sys.stderr)
        return 2
    if args.child:
        backend, kind, count, acks = args.child
        return child(backend, kind, int(count), acks == "acks")

    kinds = args.kind or list(KINDS)
    print(f"ROS port benchmark: Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, loopback")
    print()
    print(
        f"Latency, publish -> subscriber callback, one way: {args.latency_count} messages "
        f"paced at {LATENCY_RATE_HZ:.0f}/s"
    )
    header = (
        f"{'case':35} {'message':19} {'p50 us':>7} {'p99 us':>7} {'max us':>7} {'lost':>5}"
        f" {'call p50':>8} {'call p99':>8} {'sub CPU us/msg':>14}"
    )
    print(header)
    print("-" * len(header))
    for kind in kinds:
        for label, backend in CASES:
            sent, arrived, calls, cpu_s = run_case(
                backend, kind, args.latency_count, LATENCY_RATE_HZ
            )
            lat = [(arrived[s] - sent[s]) / 1000 for s in sent if s in arrived]
            call = [ns / 1000 for ns in calls.values()]
            per_msg = "-" if cpu_s is None else f"{cpu_s / max(1, len(lat)) * 1e6:.0f}"
            print(
                f"{label:35} {kind:19} {statistics.median(lat):7.0f} "
                f"{percentile(lat, 0.99):7.0f} {max(lat):7.0f} {len(sent) - len(lat):5d}"
                f" {statistics.median(call):8.0f} {percentile(call, 0.99):8.0f} {per_msg:>14}"
            )
    print()
    print(
        f"Sustained rate, nothing lost: {args.rate_count} messages, at most {WINDOW} "
        f"unacknowledged (ack every {ACK_EVERY})"
    )
    header = f"{'case':35} {'message':19} {'msgs/s':>8} {'lost':>5}"
    print(header)
    print("-" * len(header))
    for kind in kinds:
        for label, backend in CASES:
            sent, arrived, _, _ = run_case(backend, kind, args.rate_count, None)
            seconds = (max(arrived.values()) - min(sent.values())) / 1e9
            print(
                f"{label:35} {kind:19} {len(arrived) / seconds:8.0f} {len(sent) - len(arrived):5d}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

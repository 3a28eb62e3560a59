"""The ``rclpy-process`` ROS port (bridge/ros/rosport/process_backend.py): what it exists for,
a middleware that stalls cannot stall the controller link, and what happens at its
edges: a flood while the node is frozen, the node's process dying, the bridge dying.

The contract every backend keeps (names, QoS, lanes, parameters) runs on it in
test_port.py and test_node.py; here the node's process is frozen with SIGSTOP, as a
publish blocked inside Fast DDS froze the whole bridge before (CHANGELOG.md, Fixed).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bridge.ros.rosport import (
    DEFAULT_LANE,
    STOP_LANE,
    RosPort,
    RosPortError,
    UnknownBackendError,
    preload,
    qos,
)
from bridge.ros.rosport.msgs import Bool, Odometry, String
from bridge.ros.rosport.process_backend import CHILD_MODULE, ProcessPort
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from firmware_proto.runtime.realtime import (
    BRIDGE_PRIORITY,
    STOP_CHILD_PRIORITY,
    RealtimeConfig,
    module_command_at_normal_priority,
    realtime_threads,
)
from tests.bridge.conftest import VM_LINK_LOST_BEATS, WIDE_WATCHDOG_MS, Inbox
from tests.bridge.test_node import bridge_on
from tests.child import Child
from tests.procs import children

pytestmark = pytest.mark.rclpy


@pytest.fixture
def frozen() -> Iterator[Callable[[int], None]]:
    """``freeze(pid)``: SIGSTOP it; every frozen process is continued at teardown."""
    stopped: list[int] = []

    def freeze(pid: int) -> None:
        os.kill(pid, signal.SIGSTOP)
        stopped.append(pid)

    yield freeze
    for pid in stopped:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)


def _wait(predicate: Callable[[], bool], timeout_s: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def test_a_frozen_ros_node_does_not_stall_the_controller_link(
    emulators: Callable[..., Emulator],
    make_port: Callable[..., RosPort],
    frozen: Callable[[int], None],
) -> None:
    """The bridge's node frozen for 1.5 s while the rover drives: the link keeps its
    heartbeats, the controller's watchdog never fires, the step completes, and its
    ``completed``, held while the node was frozen, arrives.

    The watchdog is 1 s here, not the controller's 250 ms, and the bridge's link loss 10
    controller beats, not 3: a link that waited on the frozen node would still miss both,
    but a stall of about 200 ms does not (idle CI runs saw both of the bridge's children
    stall 165-177 ms within 4 ms, then the 250 ms watchdog or the 3-beat loss fire:
    docs/testing.md)."""
    with bridge_on(
        "rclpy-process",
        emulators,
        make_port,
        watchdog_ms=WIDE_WATCHDOG_MS,
        link_lost_beats=VM_LINK_LOST_BEATS,
    ) as (
        emu,
        node,
        client,
    ):
        pid = node.port.pid  # type: ignore[attr-defined]
        mark = client.status.mark()
        client.step(1, 60, 11500)  # 1 m at 0.6 m/s: longer than the freeze
        client.status.wait_count("accepted", 1, since=mark)
        frozen(pid)
        time.sleep(1.5)  # the stimulus: six of the protocol's watchdog periods, 1.5 here
        during = node.diagnostics()
        os.kill(pid, signal.SIGCONT)
        got = client.status.wait_count("completed", 1, since=mark, timeout=20)
        after = node.diagnostics()
    assert got == ["accepted", "completed"], got
    assert during.state == "ready", during
    assert after.heartbeat_losses == 0
    status = emu.status()
    assert status.latch == () and "watchdog" not in status.faults, status.line()


def test_a_stop_over_ros_stops_the_rover_while_the_publishing_node_is_frozen(
    emulators: Callable[..., Emulator],
    make_port: Callable[..., RosPort],
    frozen: Callable[[int], None],
) -> None:
    """The STOP lane's subscriptions live in a process that never publishes: with the
    node that publishes frozen (as a publish blocked inside Fast DDS would hold it), an
    emergency stop still reaches the link and the controller latches with its wheels'
    set-points at zero; the ``stopped`` it could not publish comes once it runs again."""
    with bridge_on("rclpy-process", emulators, make_port) as (emu, node, client):
        port = node.port
        assert isinstance(port, ProcessPort)
        client.step(1, 60, 30000)
        client.status.wait_count("accepted", 1)
        mark = client.status.mark()
        frozen(port.pid)
        client.estop.publish(Bool(data=True))
        latched = _wait(lambda: emu.status().stop_latched)
        during = emu.status()
        os.kill(port.pid, signal.SIGCONT)
        client.status.wait(lambda xs: "stopped" in xs and "aborted:stop" in xs, since=mark)
    assert latched, during.line()
    assert "stop" in during.latch and during.setpoints_mps == (0.0, 0.0), during.line()


def test_publishing_into_a_frozen_node_never_blocks_and_keeps_the_newest(
    make_port: Callable[..., RosPort], frozen: Callable[[int], None]
) -> None:
    """Far more than a socket buffer's worth of telemetry published while the node is
    frozen: every publish returns, the oldest are dropped and counted, and the newest
    reaches a subscriber once the node runs again."""
    inbox = Inbox()
    listener = make_port("rclpy", node_name="listener")
    listener.subscribe("odom", Odometry, inbox, qos.TELEMETRY)
    port = make_port("rclpy-process", node_name="talker")
    pub = port.publisher("odom", Odometry, qos.TELEMETRY)
    assert pub.wait_for_subscribers(1, timeout_s=10.0)
    frozen(port.pid)  # type: ignore[attr-defined]
    count = 5000
    finished = threading.Event()

    def flood() -> None:
        for seq in range(count):
            msg = Odometry()
            msg.header.frame_id = f"seq{seq}"
            pub.publish(msg)
        finished.set()

    thread = threading.Thread(target=flood, daemon=True)
    thread.start()
    returned = finished.wait(60.0)
    os.kill(port.pid, signal.SIGCONT)  # type: ignore[attr-defined]
    assert returned, "publish blocked on a frozen node"
    dropped = port.stats().dropped
    assert 0 < dropped < count
    assert port.stats().published == count
    newest = f"seq{count - 1}"
    inbox.wait_until(lambda msg: msg.header.frame_id == newest, timeout_s=30.0)
    seqs = [int(msg.header.frame_id[3:]) for msg in inbox.items]
    assert seqs == sorted(seqs), "published out of order"


@pytest.mark.parametrize("lane", [DEFAULT_LANE, STOP_LANE])
def test_a_node_process_dying_fails_the_port_clearly(
    make_port: Callable[..., RosPort], lane: str
) -> None:
    """Either child killed: the port says so, its lane refuses new work, and a publish
    into a dead publishing node is counted, not raised (the caller is a link thread)."""
    port = make_port("rclpy-process", node_name="doomed")
    assert isinstance(port, ProcessPort)
    pub = port.publisher("status", String, qos.STATUS)
    os.kill(port.pid if lane == DEFAULT_LANE else port.stop_pid, signal.SIGKILL)
    assert _wait(lambda: port.failure is not None)
    assert "exit status -9" in str(port.failure)
    if lane == DEFAULT_LANE:
        pub.publish(String(data="lost"))
        assert port.stats().dropped >= 1
    with pytest.raises(RosPortError, match="child process failed: it ended"):
        port.subscribe("more", String, lambda _m: None, lane=lane)
    port.close()  # returns: nothing waits for the dead child


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@contextlib.contextmanager
def _bridge(emulators: Callable[..., Emulator]) -> Iterator[tuple[Child, list[int]]]:
    """``rover bridge`` on an emulator's pty, running; yields it and its nodes' pids."""
    emu = emulators()
    assert isinstance(emu.frontend, SerialFrontEnd)
    bridge = Child(["bridge", "--device", emu.frontend.device], dict(os.environ))
    try:
        assert bridge.wait_for("BRIDGE ").endswith(" rclpy-process")
        nodes = sorted(children(bridge.proc.pid))
        assert len(nodes) == 2, nodes  # the node, and the STOP lane's node
        yield bridge, nodes
    finally:
        bridge.proc.kill()
        bridge.wait(10)


def test_the_bridge_exits_with_an_error_when_its_node_process_dies(
    emulators: Callable[..., Emulator],
) -> None:
    with _bridge(emulators) as (bridge, nodes):
        os.kill(nodes[0], signal.SIGKILL)
        status = bridge.wait(20)
    err = "\n".join(bridge.errors)
    assert status == 1, err
    assert "rover bridge: error: the ROS 2 node failed: it ended (exit status -9)" in err
    assert "Traceback" not in err


def test_the_node_process_ends_when_the_bridge_is_killed(
    emulators: Callable[..., Emulator],
) -> None:
    with _bridge(emulators) as (bridge, nodes):
        bridge.proc.kill()  # no clean-up runs in the bridge
        bridge.wait(10)
        assert _wait(lambda: not any(_alive(node) for node in nodes)), "a node outlived it"


def test_a_node_that_cannot_start_is_an_error_naming_the_reason(
    make_port: Callable[..., RosPort],
) -> None:
    with pytest.raises(RosPortError, match=r"node 'bad' in a child: .*trailing -r flag"):
        make_port("rclpy-process", node_name="bad", args=["--ros-args", "-r"])


def _scheduling(pid: int, tid: int | None = None) -> tuple[int, int]:
    """(policy, real-time priority) of a process's main thread (or thread ``tid``), from
    /proc."""
    task = f"/proc/{pid}/task/{tid}/stat" if tid is not None else f"/proc/{pid}/stat"
    fields = Path(task).read_text().rsplit(")", 1)[1].split()
    return int(fields[38]), int(fields[37])


@pytest.mark.skipif(os.geteuid() != 0, reason="granting real time needs root here")
@pytest.mark.parametrize("owner_realtime", [True, False], ids=["realtime-owner", "normal-owner"])
def test_the_node_processes_take_their_own_scheduling_after_their_imports(
    make_port: Callable[..., RosPort], owner_realtime: bool
) -> None:
    """The children start at normal priority whatever their owner's (their imports and
    their node's start must not hold a core at the link's priority: docs/realtime.md);
    then, where the owner keeps real time, the STOP lane's child takes ``SCHED_RR`` 15,
    every thread of it, the middleware's too, and the publishing child stays at normal
    scheduling; where it does not, neither takes real time."""
    config = RealtimeConfig(BRIDGE_PRIORITY if owner_realtime else 0, lock_memory=False)
    with realtime_threads(config):
        port = make_port("rclpy-process", node_name="scheduled")
    assert isinstance(port, ProcessPort)
    launcher = module_command_at_normal_priority(CHILD_MODULE)
    for pid in (port.pid, port.stop_pid):
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
        assert argv[: len(launcher)] == launcher
    assert _scheduling(port.pid) == (os.SCHED_OTHER, 0)
    expected = (os.SCHED_RR, STOP_CHILD_PRIORITY) if owner_realtime else (os.SCHED_OTHER, 0)
    assert _scheduling(port.stop_pid) == expected
    threads = [int(tid) for tid in os.listdir(f"/proc/{port.stop_pid}/task")]
    assert len(threads) > 3  # the middleware's threads, this test's point
    assert {_scheduling(port.stop_pid, tid) for tid in threads} == {expected}


def test_preload_imports_what_opening_the_port_imports() -> None:
    """A real-time program preloads its backend before it takes real time (imports are
    CPU-bound: at real-time priority they hold a core from everything else;
    docs/realtime.md): opening an ``rclpy-process`` port, a publisher and a subscription
    after it import no module more."""
    code = textwrap.dedent(
        """
        import sys
        from bridge.ros.rosport import open_port, preload, qos
        from bridge.ros.rosport.msgs import String

        preload("rclpy-process")
        before = set(sys.modules)
        with open_port("rclpy-process", node_name="preload_probe") as port:
            port.publisher("/preload_probe", String, qos.STATUS)
            port.subscribe("/preload_probe", String, lambda message: None, qos.STATUS)
        print(sorted(set(sys.modules) - before))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).resolve().parents[2],
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout


def test_preload_refuses_an_unknown_backend_by_name() -> None:
    with pytest.raises(UnknownBackendError, match="no-such"):
        preload("no-such")

"""The ``rclpy-process`` backend: real ROS 2 nodes in child processes of their own.

Why: rclpy calls into the middleware holding Python's interpreter lock, so a blocked
publish would stop every thread of the process, the controller link's included; here no
middleware call runs in the caller's process. What the caller sees is a
:class:`~bridge.ros.rosport.port.RosPort` like any other; how it works underneath is
docs/rosport.md, "``rclpy-process``". The contracts:

- messages cross as their CDR bytes; the parent never initialises rclpy;
- ``publish`` serializes, queues and returns: it never waits for the child. A writer
  holds at most its QoS ``depth`` messages that the child has not taken; older ones are
  dropped and counted in :attr:`~bridge.ros.rosport.port.PortStats.dropped`;
- requests (endpoints, parameters, matched counts) wait for the child's answer at most
  :data:`REQUEST_TIMEOUT_S` and raise :class:`RosPortError` after that;
- a child ends when the parent closes the port, and by itself when the parent dies. If
  either dies, :attr:`ProcessPort.failure` says so and every later request to it
  raises; publishes into a dead publishing node are dropped and counted.

The cost is a serialization per message on each side and a socket hop
(``benchmarks/bench_rosport.py``).
"""

from __future__ import annotations

import collections
import contextlib
import importlib
import itertools
import logging
import os
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Final

from bridge.errors import ParameterError
from bridge.ros.rosport.errors import BackendUnavailableError, PortClosedError, RosPortError
from bridge.ros.rosport.names import ros_type_name
from bridge.ros.rosport.parameters import ParameterSpec, ParameterValue
from bridge.ros.rosport.port import (
    DEFAULT_LANE,
    DEFAULT_NODE_NAME,
    STOP_LANE,
    Message,
    RosPort,
    Subscription,
)
from bridge.ros.rosport.qos import Qos
from firmware_proto.runtime.realtime import in_realtime, module_command_at_normal_priority

__all__ = [
    "CHILD_MODULE",
    "PARENT_REALTIME_ENV",
    "REQUEST_TIMEOUT_S",
    "START_TIMEOUT_S",
    "ProcessPort",
]

logger = logging.getLogger(__name__)

#: The module the child runs (``python -m``).
CHILD_MODULE: Final = "bridge.ros.rosport.process_child"
PARENT_REALTIME_ENV: Final = "ROVER_PARENT_REALTIME"
"""Set in a child's environment: ``1`` when the port's owner ran at real time."""
#: How long the child may take to start its node and say so, s.
START_TIMEOUT_S: Final = 30.0
#: How long a request waits for the child's answer, s.
REQUEST_TIMEOUT_S: Final = 10.0
#: How long ``close()`` waits for the child to exit before killing it, s.
EXIT_TIMEOUT_S: Final = 5.0
#: Poll period of the lane and reply threads: each notices a close this soon, s.
_POLL_S: Final = 0.2


def _serialization() -> Any:
    try:
        return importlib.import_module("rclpy.serialization")
    except ImportError as exc:
        raise BackendUnavailableError(
            "rclpy is not installed: install this project with its 'ros' extra "
            f"(pip install 'rover-hil[ros]') or source /opt/ros/jazzy/setup.bash ({exc})"
        ) from exc


def _child_env() -> dict[str, str]:
    """This environment, with the directory this ``bridge`` package was imported from
    first on ``PYTHONPATH``: the child runs the same code, wherever the parent started."""
    root = str(Path(__file__).resolve().parents[3])
    rest = os.environ.get("PYTHONPATH", "")
    return {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (root, rest) if p),
        # The child starts at normal priority; this says whether its parent keeps time.
        PARENT_REALTIME_ENV: "1" if in_realtime() else "0",
    }


class _Outbox:
    """Parent-to-child traffic in order, on one sender thread, never blocking the caller.

    Items are ``("pub", writer_id, cdr)`` or any other request tuple. A writer holds at
    most its ``depth`` publishes that are not sent yet: the oldest one goes (counted) when
    another comes. Requests are never dropped.
    """

    def __init__(self, conn: Connection, on_drop: Callable[[], object], name: str) -> None:
        self._conn = conn
        self._on_drop = on_drop
        self._items: collections.deque[tuple[Any, ...]] = collections.deque()
        self._pending: collections.Counter[int] = collections.Counter()
        self._cond = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def publish(self, writer_id: int, depth: int, cdr: bytes) -> None:
        with self._cond:
            if self._closing:
                self._on_drop()
                return
            if self._pending[writer_id] >= depth:
                for index, item in enumerate(self._items):
                    if item[0] == "pub" and item[1] == writer_id:
                        del self._items[index]
                        self._pending[writer_id] -= 1
                        self._on_drop()
                        break
            self._items.append(("pub", writer_id, cdr))
            self._pending[writer_id] += 1
            self._cond.notify()

    def request(self, item: tuple[Any, ...]) -> None:
        with self._cond:
            if self._closing:
                raise PortClosedError("the ROS 2 child process is closing")
            self._items.append(item)
            self._cond.notify()

    def close(self, last: tuple[Any, ...] | None, timeout_s: float) -> None:
        """Send what is queued, then ``last``; stop the thread (waits ``timeout_s``)."""
        with self._cond:
            if last is not None:
                self._items.append(last)
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._items and not self._closing:
                    self._cond.wait(_POLL_S)
                if not self._items:
                    return
                item = self._items.popleft()
                if item[0] == "pub":
                    self._pending[item[1]] -= 1
            try:
                self._conn.send(item)
            except (OSError, ValueError) as exc:  # the child is gone
                logger.debug("ROS 2 child: sending failed: %s", exc)
                with self._cond:
                    dropped = sum(1 for i in self._items if i[0] == "pub")
                    self._items.clear()
                    self._pending.clear()
                    self._closing = True
                for _ in range(dropped + (item[0] == "pub")):
                    self._on_drop()
                return


class _Child:
    """One child process with an rclpy node: its two sockets (``ctl``: requests, publishes
    and replies; ``msg``: deliveries), the sender and the reply thread. ``on_set`` answers
    the node's parameter changes; ``on_fail`` is told once if the child dies."""

    def __init__(
        self,
        label: str,
        init: tuple[Any, ...],
        on_drop: Callable[[], object],
        on_set: Callable[[dict[str, Any]], str | None],
        on_fail: Callable[[str], object],
    ) -> None:
        self.label = label
        self._on_drop = on_drop
        self._on_set = on_set
        self._on_fail = on_fail
        self._ids = itertools.count(1)
        self._replies: dict[int, list[Any]] = {}
        self._replies_cond = threading.Condition()
        self._closing = threading.Event()
        self.failure: str | None = None
        pairs = {name: socket.socketpair() for name in ("ctl", "msg")}
        try:
            # At normal priority from its first line: its imports must not hold a core
            # at the link's priority; it asks for its own once it is ready (_schedule).
            self.proc = subprocess.Popen(
                module_command_at_normal_priority(CHILD_MODULE)
                + [f"{name}={theirs.fileno()}" for name, (_, theirs) in pairs.items()],
                pass_fds=[theirs.fileno() for _, theirs in pairs.values()],
                stdin=subprocess.DEVNULL,
                env=_child_env(),
            )
        except OSError as exc:
            for ours, theirs in pairs.values():
                ours.close()
                theirs.close()
            raise RosPortError(f"cannot start the ROS 2 child process: {exc}") from exc
        self.conns: dict[str, Connection] = {}
        for name, (ours, theirs) in pairs.items():
            theirs.close()
            self.conns[name] = Connection(ours.detach())
        try:
            self.conns["ctl"].send(init)
        except OSError as exc:
            self.end()
            raise RosPortError(f"cannot start the ROS 2 child process: {exc}") from exc
        self.outbox: _Outbox | None = None
        self._rx: threading.Thread | None = None

    def await_ready(self, deadline: float) -> str:
        """The child's middleware once its node is up; raises (and ends it) otherwise."""
        ctl = self.conns["ctl"]
        try:
            ready = ctl.poll(max(0.0, deadline - time.monotonic()))
            answer = ctl.recv() if ready else None
        except (OSError, EOFError) as exc:
            answer = ("error", f"it ended ({exc})")
        if answer is None or answer[0] != "ready":
            self.end()
            why = f"no answer in {START_TIMEOUT_S:.0f} s" if answer is None else answer[1]
            raise RosPortError(f"cannot start the ROS 2 node {self.label!r} in a child: {why}")
        self.outbox = _Outbox(ctl, self._on_drop, f"rosport-{self.label}-tx")
        self._rx = threading.Thread(
            target=self._receive_replies, name=f"rosport-{self.label}-replies", daemon=True
        )
        self._rx.start()
        middleware: str = answer[1]
        return middleware

    def post(self, item: tuple[Any, ...]) -> None:
        """A request that needs no answer (closing an endpoint); ignored once closed."""
        if self.outbox is not None:
            with contextlib.suppress(PortClosedError):
                self.outbox.request(item)

    def call(self, op: str, *payload: Any) -> Any:
        """Send a request and wait for its answer; the child's error is raised here."""
        if self.failure is not None or self.outbox is None:
            raise RosPortError(f"the ROS 2 child process failed: {self.failure}")
        request_id = next(self._ids)
        with self._replies_cond:
            self._replies[request_id] = []
        self.outbox.request((op, request_id, *payload))
        deadline = time.monotonic() + REQUEST_TIMEOUT_S
        with self._replies_cond:
            while not self._replies[request_id]:
                left = deadline - time.monotonic()
                if left <= 0 or self.failure is not None:
                    del self._replies[request_id]
                    why = self.failure or f"no answer to {op!r} in {REQUEST_TIMEOUT_S:.0f} s"
                    raise RosPortError(f"the ROS 2 child process: {why}")
                self._replies_cond.wait(left)
            status, value = self._replies.pop(request_id)[0]
        if status == "ok":
            return value
        if status == "parameter":
            raise ParameterError(value)
        raise RosPortError(value)

    def _receive_replies(self) -> None:
        ctl = self.conns["ctl"]
        while not self._closing.is_set():
            try:
                if not ctl.poll(_POLL_S):
                    continue
                item = ctl.recv()
            except (OSError, EOFError):
                break
            if item[0] == "reply":
                _, request_id, status, value = item
                with self._replies_cond:
                    if request_id in self._replies:
                        self._replies[request_id].append((status, value))
                        self._replies_cond.notify_all()
            elif item[0] == "on_set":
                _, request_id, values = item
                self.post(("on_set_reply", request_id, self._on_set(values)))
        if not self._closing.is_set():
            try:  # its sockets close as it exits: the status follows at once
                code: int | None = self.proc.wait(_POLL_S)
            except subprocess.TimeoutExpired:
                code = None
            self.failure = f"it ended (exit status {code})" if code is not None else "it hung up"
            with self._replies_cond:
                self._replies_cond.notify_all()
            self._on_fail(self.failure)

    def close(self) -> None:
        """Tell the child to close its node, wait for it (kill it if it does not end)."""
        self._closing.set()
        if self.outbox is not None:
            self.outbox.close(("close",), EXIT_TIMEOUT_S)
        if self._rx is not None:
            self._rx.join(EXIT_TIMEOUT_S)
        self.end()

    def end(self) -> None:
        """Close the sockets (the child reads end of file and exits); reap it."""
        self._closing.set()
        for conn in self.conns.values():
            conn.close()
        try:
            self.proc.wait(EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            logger.error("ROS 2 child %s did not exit; killing it", self.label)
            self.proc.kill()
            self.proc.wait(EXIT_TIMEOUT_S)


class _Writer:
    def __init__(self, port: ProcessPort, writer_id: int, depth: int) -> None:
        self._port = port
        self._id = writer_id
        self._depth = depth

    def write(self, msg: Message) -> None:
        self._port._publish(self._id, self._depth, msg)

    def write_serialized(self, cdr: bytes) -> None:
        self._port._publish_serialized(self._id, self._depth, cdr)

    def matched_count(self) -> int:
        return int(self._port._main.call("matched", self._id))

    def close(self) -> None:
        self._port._main.post(("close_writer", self._id))


class _Reader:
    def __init__(self, port: ProcessPort, child: _Child, reader_id: int) -> None:
        self._port = port
        self._child = child
        self._id = reader_id

    def matched_count(self) -> int:
        return int(self._child.call("sub_matched", self._id))

    def close(self) -> None:
        with self._port._readers_lock:
            self._port._readers.pop((self._child.label, self._id), None)
        self._child.post(("close_reader", self._id))


class ProcessPort(RosPort):
    """A port whose rclpy nodes run in child processes (``open_port("rclpy-process")``).

    Two children: the node ``node_name``, which publishes, owns the parameters and takes
    the default lane's subscriptions; and the node ``<node_name>_stop``, which takes only
    the STOP lane's and never publishes, so a STOP never waits for the interpreter of a
    process that is publishing.

    Args:
        namespace, node_name: see :class:`RosPort` (also the nodes').
        domain_id: ROS domain; default ``$ROS_DOMAIN_ID``, else 0.
        args: ROS command-line arguments for both nodes (``["--ros-args", ...]``).

    Raises:
        BackendUnavailableError: rclpy is not installed.
        RosPortError: a child did not start its node (its reason), or not in
            :data:`START_TIMEOUT_S`.
    """

    backend = "rclpy-process"
    carries_serialized = True

    def __init__(
        self,
        *,
        namespace: str = "",
        node_name: str = DEFAULT_NODE_NAME,
        domain_id: int | None = None,
        args: Sequence[str] = (),
    ) -> None:
        super().__init__(namespace=namespace, node_name=node_name)
        self._ser = _serialization()
        self._readers: dict[tuple[str, int], Subscription[Any]] = {}
        self._readers_lock = threading.Lock()
        # Both start at once (each imports rclpy and makes a node).
        children: dict[str, _Child] = {}
        try:
            for lane, name in ((DEFAULT_LANE, node_name), (STOP_LANE, node_name + "_stop")):
                children[lane] = _Child(
                    name,
                    ("init", self.namespace, name, domain_id, list(args), lane == STOP_LANE),
                    self._count_dropped,
                    self._answer_on_set,
                    self._log_failure,
                )
            deadline = time.monotonic() + START_TIMEOUT_S
            middleware = [child.await_ready(deadline) for child in children.values()]
        except RosPortError:
            for child in children.values():
                child.end()
            raise
        self._children = children
        self._main = children[DEFAULT_LANE]
        #: What the children run: ``"rmw_fastrtps_cpp (rclpy 7.1.6)"``.
        self.middleware: str = middleware[0]
        self._start()

    @property
    def pid(self) -> int:
        """The process id of the child that publishes (the node ``node_name``)."""
        return self._main.proc.pid

    @property
    def stop_pid(self) -> int:
        """The process id of the child that takes the STOP lane's subscriptions."""
        return self._children[STOP_LANE].proc.pid

    @property
    def failure(self) -> str | None:
        """Why a child is gone when it ended without being closed; else ``None``."""
        return next((c.failure for c in self._children.values() if c.failure), None)

    def _log_failure(self, why: str) -> None:
        logger.error("%s: a ROS 2 child process failed: %s", self, why)

    def _answer_on_set(self, values: dict[str, Any]) -> str | None:
        """A parameter change made from outside, through the child: the node decides."""
        with self._param_lock:
            on_set = self._on_set
        try:
            return on_set(values) if on_set is not None else None
        except Exception as exc:  # the node's callback failed: refuse the change
            logger.exception("%s: on_set raised", self)
            return f"the node failed to apply it: {exc}"

    # -- parameters -------------------------------------------------------------------
    def _declare_parameters(
        self, specs: list[ParameterSpec], values: dict[str, ParameterValue]
    ) -> dict[str, ParameterValue]:
        declared: dict[str, ParameterValue] = self._main.call("declare", specs, values)
        return declared

    def _set_parameters(self, values: dict[str, Any]) -> str | None:
        reason: str | None = self._main.call("set", values)
        return reason

    def _get_parameters(self) -> dict[str, ParameterValue]:
        current: dict[str, ParameterValue] = self._main.call("get")
        return current

    # -- endpoints --------------------------------------------------------------------
    def _open_writer(self, topic: str, msg_type: type[Any], qos: Qos) -> _Writer:
        writer_id = self._main.call("writer", topic, ros_type_name(msg_type), qos)
        return _Writer(self, writer_id, qos.depth)

    def _publish(self, writer_id: int, depth: int, msg: Message) -> None:
        outbox = self._main.outbox
        if self._main.failure is not None or outbox is None:
            self._count_dropped()
            return
        outbox.publish(writer_id, depth, self._ser.serialize_message(msg))

    def _publish_serialized(self, writer_id: int, depth: int, cdr: bytes) -> None:
        outbox = self._main.outbox
        if self._main.failure is not None or outbox is None:
            self._count_dropped()
            return
        outbox.publish(writer_id, depth, cdr)  # the child publishes it as it is

    def _open_reader(self, sub: Subscription[Any]) -> _Reader:
        child = self._children[sub.lane]
        reader_id = child.call("reader", sub.topic, ros_type_name(sub.msg_type), sub.qos)
        with self._readers_lock:
            self._readers[(child.label, reader_id)] = sub
        return _Reader(self, child, reader_id)

    def _run(self, lane: str) -> None:
        child = self._children[lane]
        conn = child.conns["msg"]
        while not self._stopping.is_set():
            try:
                if not conn.poll(_POLL_S):
                    continue
                _, reader_id, cdr = conn.recv()
            except (OSError, EOFError):
                return  # the child is gone; its reply thread says why
            with self._readers_lock:
                sub = self._readers.get((child.label, reader_id))
            if sub is None:
                continue  # closed while the message was on its way
            if sub.serialized:
                self._deliver(sub, cdr)  # as the child took it
                continue
            try:
                msg = self._ser.deserialize_message(cdr, sub.msg_type)
            except Exception:
                logger.exception("%s: a message on %s did not deserialize", self, sub.topic)
                continue
            self._deliver(sub, msg)

    def _release(self) -> None:
        for child in self._children.values():
            child.close()

    def __repr__(self) -> str:
        children = getattr(self, "_children", {})
        pids = ",".join(str(child.proc.pid) for child in children.values())
        return super().__repr__()[:-1] + (f" children {pids}" if pids else "") + ">"

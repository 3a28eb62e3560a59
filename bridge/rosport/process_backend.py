"""The ``rclpy-process`` backend: a real ROS 2 node in a child process of its own.

Why: rclpy calls into the middleware (``Publisher.publish`` into Fast DDS) while holding
Python's interpreter lock, and Fast DDS publishes on the caller's thread (Jazzy's
default, synchronous). When such a call blocks, every thread of the process stops with
it. In the bridge that was the controller link: heartbeats, STOP, the reader. A publish of
``/odom`` was caught blocking for 340 ms and then 354 ms inside the demo, and the motor
controller's 250 ms watchdog stopped the rover (README, "Known defect", now fixed).
Here the node lives in another process, so no middleware call can stop the link's threads.

What the caller sees is a :class:`~bridge.rosport.port.RosPort` like any other: the same
names, QoS, lanes, taps, parameters and counters. Underneath:

- the parent spawns ``python -m bridge.rosport.process_child`` with three socket pairs:
  one for requests and publishes (parent to child, in order) and replies (child to
  parent), and one per lane for deliveries (child to parent), so a STOP never queues
  behind telemetry in a pipe either;
- messages cross as their CDR bytes (``rclpy.serialization``: no middleware, no context);
  the parent never initialises rclpy;
- ``publish`` serializes and queues, and returns: it never waits for the child. A writer
  holds at most its QoS ``depth`` messages that the child has not taken (the keep-last
  rule DDS applies anyway); older ones are dropped and counted in
  :attr:`~bridge.rosport.port.PortStats.dropped`, so a stalled middleware costs telemetry
  samples, never memory or the caller's time;
- requests (endpoints, parameters, matched counts) wait for the child's answer at most
  :data:`REQUEST_TIMEOUT_S` and raise :class:`RosPortError` after that;
- a parameter change made from outside (``ros2 param set``) reaches the node's
  ``on_set`` in this process through the child, and its answer goes back;
- the child ends when the parent closes the port, and by itself when the parent dies (its
  request socket reaches end of file). If the child dies, :attr:`ProcessPort.failure`
  says so, every later request raises, and publishes are dropped and counted.

The CPU cost is a serialization per message on each side and a socket hop: measured in
``benchmarks/bench_rosport.py`` beside the in-process ``rclpy`` backend.
"""

from __future__ import annotations

import collections
import contextlib
import importlib
import itertools
import logging
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any, Final

from bridge.errors import ParameterError
from bridge.rosport.errors import BackendUnavailableError, PortClosedError, RosPortError
from bridge.rosport.names import ros_type_name
from bridge.rosport.parameters import ParameterSpec, ParameterValue
from bridge.rosport.port import (
    DEFAULT_NODE_NAME,
    LANES,
    Message,
    RosPort,
    Subscription,
)
from bridge.rosport.qos import Qos

__all__ = ["CHILD_MODULE", "REQUEST_TIMEOUT_S", "START_TIMEOUT_S", "ProcessPort"]

logger = logging.getLogger(__name__)

#: The module the child runs (``python -m``).
CHILD_MODULE: Final = "bridge.rosport.process_child"
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


class _Writer:
    def __init__(self, port: ProcessPort, writer_id: int, depth: int) -> None:
        self._port = port
        self._id = writer_id
        self._depth = depth

    def write(self, msg: Message) -> None:
        self._port._publish(self._id, self._depth, msg)

    def matched_count(self) -> int:
        return int(self._port._call("matched", self._id))

    def close(self) -> None:
        self._port._post(("close_writer", self._id))


class _Reader:
    def __init__(self, port: ProcessPort, reader_id: int) -> None:
        self._port = port
        self._id = reader_id

    def matched_count(self) -> int:
        return int(self._port._call("sub_matched", self._id))

    def close(self) -> None:
        with self._port._readers_lock:
            self._port._readers.pop(self._id, None)
        self._port._post(("close_reader", self._id))


class ProcessPort(RosPort):
    """A port whose rclpy node runs in a child process (``open_port("rclpy-process")``).

    Args:
        namespace: see :class:`RosPort` (also the node's namespace).
        node_name: see :class:`RosPort` (also the node's name).
        domain_id: ROS domain; default ``$ROS_DOMAIN_ID``, else 0.
        args: ROS command-line arguments for the node (``["--ros-args", ...]``).

    Raises:
        BackendUnavailableError: rclpy is not installed.
        RosPortError: the child did not start its node (its reason), or not in
            :data:`START_TIMEOUT_S`.
    """

    backend = "rclpy-process"

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
        self._ids = itertools.count(1)
        self._replies: dict[int, list[Any]] = {}
        self._replies_cond = threading.Condition()
        self._readers: dict[int, Subscription[Any]] = {}
        self._readers_lock = threading.Lock()
        self._failure: str | None = None
        pairs = {name: socket.socketpair() for name in ("ctl", *LANES)}
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", CHILD_MODULE]
                + [f"{name}={theirs.fileno()}" for name, (_, theirs) in pairs.items()],
                pass_fds=[theirs.fileno() for _, theirs in pairs.values()],
                stdin=subprocess.DEVNULL,
            )
        except OSError as exc:
            for ours, theirs in pairs.values():
                ours.close()
                theirs.close()
            raise RosPortError(f"cannot start the ROS 2 child process: {exc}") from exc
        self._conns: dict[str, Connection] = {}
        for name, (ours, theirs) in pairs.items():
            theirs.close()
            self._conns[name] = Connection(ours.detach())
        ctl = self._conns["ctl"]
        try:
            ctl.send(("init", self.namespace, self.node_name, domain_id, list(args)))
            ready = ctl.poll(START_TIMEOUT_S)
            answer = ctl.recv() if ready else None
        except (OSError, EOFError) as exc:
            answer = ("error", f"it ended ({exc})")
        if answer is None or answer[0] != "ready":
            why = f"no answer in {START_TIMEOUT_S:.0f} s" if answer is None else answer[1]
            self._end_child()
            raise RosPortError(f"cannot start the ROS 2 node {node_name!r} in a child: {why}")
        #: What the child runs: ``"rmw_fastrtps_cpp (rclpy 7.1.6)"``.
        self.middleware: str = answer[1]
        self._outbox = _Outbox(ctl, self._count_dropped, f"rosport-{node_name}-tx")
        self._rx = threading.Thread(
            target=self._receive_replies, name=f"rosport-{node_name}-replies", daemon=True
        )
        self._rx.start()
        self._start()

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self._proc.pid

    @property
    def failure(self) -> str | None:
        """Why the child is gone when it ended without being closed; else ``None``."""
        return self._failure

    # -- requests ---------------------------------------------------------------------
    def _post(self, item: tuple[Any, ...]) -> None:
        """A request that needs no answer (closing an endpoint); ignored once closed."""
        with contextlib.suppress(PortClosedError):
            self._outbox.request(item)

    def _call(self, op: str, *payload: Any) -> Any:
        """Send a request and wait for its answer; the child's error is raised here."""
        if self._failure is not None:
            raise RosPortError(f"the ROS 2 child process failed: {self._failure}")
        request_id = next(self._ids)
        with self._replies_cond:
            self._replies[request_id] = []
        self._outbox.request((op, request_id, *payload))
        deadline = time.monotonic() + REQUEST_TIMEOUT_S
        with self._replies_cond:
            while not self._replies[request_id]:
                left = deadline - time.monotonic()
                if left <= 0 or self._failure is not None:
                    del self._replies[request_id]
                    why = self._failure or f"no answer to {op!r} in {REQUEST_TIMEOUT_S:.0f} s"
                    raise RosPortError(f"the ROS 2 child process: {why}")
                self._replies_cond.wait(left)
            ok, value = self._replies.pop(request_id)[0]
        if ok == "ok":
            return value
        if ok == "parameter":
            raise ParameterError(value)
        raise RosPortError(value)

    def _receive_replies(self) -> None:
        ctl = self._conns["ctl"]
        while not self._stopping.is_set():
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
                with self._param_lock:
                    on_set = self._on_set
                try:
                    reason = on_set(values) if on_set is not None else None
                except Exception as exc:  # the node's callback failed: refuse the change
                    logger.exception("%s: on_set raised", self)
                    reason = f"the node failed to apply it: {exc}"
                self._post(("on_set_reply", request_id, reason))
        if not self._stopping.is_set():
            try:  # its sockets close as it exits: the status follows at once
                code: int | None = self._proc.wait(_POLL_S)
            except subprocess.TimeoutExpired:
                code = None
            self._fail(f"it ended (exit status {code})" if code is not None else "it hung up")

    def _fail(self, why: str) -> None:
        self._failure = why
        logger.error("%s: the ROS 2 child process failed: %s", self, why)
        with self._replies_cond:
            self._replies_cond.notify_all()

    # -- parameters -------------------------------------------------------------------
    def _declare_parameters(
        self, specs: list[ParameterSpec], values: dict[str, ParameterValue]
    ) -> dict[str, ParameterValue]:
        declared: dict[str, ParameterValue] = self._call("declare", specs, values)
        return declared

    def _set_parameters(self, values: dict[str, Any]) -> str | None:
        reason: str | None = self._call("set", values)
        return reason

    def _get_parameters(self) -> dict[str, ParameterValue]:
        current: dict[str, ParameterValue] = self._call("get")
        return current

    # -- endpoints --------------------------------------------------------------------
    def _open_writer(self, topic: str, msg_type: type[Any], qos: Qos) -> _Writer:
        writer_id = self._call("writer", topic, ros_type_name(msg_type), qos)
        return _Writer(self, writer_id, qos.depth)

    def _publish(self, writer_id: int, depth: int, msg: Message) -> None:
        if self._failure is not None:
            self._count_dropped()
            return
        self._outbox.publish(writer_id, depth, self._ser.serialize_message(msg))

    def _open_reader(self, sub: Subscription[Any]) -> _Reader:
        reader_id = self._call("reader", sub.topic, ros_type_name(sub.msg_type), sub.qos, sub.lane)
        with self._readers_lock:
            self._readers[reader_id] = sub
        return _Reader(self, reader_id)

    def _run(self, lane: str) -> None:
        conn = self._conns[lane]
        while not self._stopping.is_set():
            try:
                if not conn.poll(_POLL_S):
                    continue
                _, reader_id, cdr = conn.recv()
            except (OSError, EOFError):
                return  # the child is gone; the reply thread says why
            with self._readers_lock:
                sub = self._readers.get(reader_id)
            if sub is None:
                continue  # closed while the message was on its way
            try:
                msg = self._ser.deserialize_message(cdr, sub.msg_type)
            except Exception:
                logger.exception("%s: a message on %s did not deserialize", self, sub.topic)
                continue
            self._deliver(sub, msg)

    def _release(self) -> None:
        self._outbox.close(("close",), EXIT_TIMEOUT_S)
        self._rx.join(EXIT_TIMEOUT_S)
        self._end_child()

    def _end_child(self) -> None:
        for conn in self._conns.values():
            conn.close()  # the child reads end of file and exits
        try:
            self._proc.wait(EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            logger.error("%s: the ROS 2 child did not exit; killing it", self)
            self._proc.kill()
            self._proc.wait(EXIT_TIMEOUT_S)

    def __repr__(self) -> str:
        proc = getattr(self, "_proc", None)
        child = f" child pid {proc.pid}" if proc is not None else ""
        return super().__repr__()[:-1] + child + ">"

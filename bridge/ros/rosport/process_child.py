"""The child of :class:`~bridge.ros.rosport.process_backend.ProcessPort`: an rclpy node that
does what its parent asks, and nothing else.

Started as ``python -m bridge.ros.rosport.process_child ctl=FD msg=FD`` with the child ends
of the parent's socket pairs (the parent starts two: one for the node that publishes,
one for the STOP lane's node). The first thing on ``ctl`` is
``("init", namespace, node_name, domain_id, args, stop_only)``; the answer is ``("ready",
middleware)`` or ``("error", reason)``. After that, on ``ctl``, in order:

- ``("writer", id, topic, type, qos)``, ``("reader", id, topic, type, qos)``,
  ``("matched", id, writer)``, ``("sub_matched", id, reader)``,
  ``("declare", id, specs, values)``, ``("set", id, values)``, ``("get", id)``: each
  answered ``("reply", id, status, value)``, status ``"ok"``,
  ``"parameter"`` (a refused parameter) or ``"error"``;
- ``("pub", writer, cdr)``: publish the serialized message as it is
  (:meth:`RclpyPort.publish_serialized`; no answer; a failure is logged and counted);
- ``("close_writer", writer)``, ``("close_reader", reader)``: no answer;
- ``("on_set_reply", id, reason)``: the parent's answer to this child's
  ``("on_set", id, values)``, sent when a parameter change reaches the node;
- ``("close",)``, or end of file (the parent died): close the node and exit 0.

Each message a reader takes goes to the parent on ``msg`` as ``("msg", reader, cdr)``;
the STOP child (``stop_only``) takes every reader on its node's rcl wait set, as the
rclpy backend's STOP lane does; the other on its default lane's wait set, which also
holds the node's parameter services.

SIGINT and SIGTERM are ignored: the parent decides when this process ends (a Ctrl-C
reaches the whole process group, and the parent must close the node itself).
"""

from __future__ import annotations

import importlib
import itertools
import logging
import os
import queue
import signal
import sys
import threading
from collections.abc import Mapping, Sequence
from multiprocessing.connection import Connection
from typing import Any

from bridge.errors import ParameterError
from bridge.ros.rosport.port import DEFAULT_LANE, STOP_LANE, Publisher, Subscription
from bridge.ros.rosport.process_backend import PARENT_REALTIME_ENV, REQUEST_TIMEOUT_S
from bridge.ros.rosport.rclpy_backend import RclpyPort, middleware
from firmware_proto.runtime.procname import set_process_name
from firmware_proto.runtime.realtime import (
    STOP_CHILD_PRIORITY,
    RealtimeConfig,
    apply_realtime_to_process,
    leave_realtime_for_process,
)
from firmware_proto.runtime.stall import StallMonitor, stall_log_path

__all__ = ["Child", "main", "message_type"]

logger = logging.getLogger("bridge.ros.rosport.process_child")


def message_type(name: str) -> type[Any]:
    """The generated class of ``"pkg/msg/Name"``."""
    package, kind, cls = name.split("/")
    found: type[Any] = getattr(importlib.import_module(f"{package}.{kind}"), cls)
    return found


class Child:
    """The node's side of the sockets (see the module docstring)."""

    def __init__(self, conns: Mapping[str, Connection]) -> None:
        self._ctl = conns["ctl"]
        self._msg = conns["msg"]
        self._send_lock = threading.Lock()
        self._msg_lock = threading.Lock()
        self._work: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._answers: dict[int, queue.Queue[str | None]] = {}
        self._ids = itertools.count(1)
        self._lane = DEFAULT_LANE
        self._writers: dict[int, Publisher[Any]] = {}
        self._readers: dict[int, Subscription[Any]] = {}
        self._ser = importlib.import_module("rclpy.serialization")
        self.publish_errors = 0

    def _send(self, item: tuple[Any, ...]) -> None:
        with self._send_lock:
            self._ctl.send(item)

    def run(self) -> int:
        """Start the node, serve the parent until it closes or dies; the exit status."""
        try:
            _, namespace, node_name, domain_id, args, stop_only = self._ctl.recv()
        except (EOFError, OSError):
            return 1
        self._lane = STOP_LANE if stop_only else DEFAULT_LANE
        # Its stalls (a middleware call holding the interpreter lock) are logged and go
        # to the stack's stall log under the node's name (docs/realtime.md, Stalls).
        monitor = StallMonitor(node_name, log_path=stall_log_path())
        with monitor:
            return self._serve(namespace, node_name, domain_id, args, stop_only)

    def _serve(
        self, namespace: str, node_name: str, domain_id: int | None, args: Any, stop_only: bool
    ) -> int:
        try:
            port = RclpyPort(
                namespace=namespace,
                node_name=node_name,
                domain_id=domain_id,
                args=args,
                stop_only=stop_only,
            )
        except Exception as exc:  # the parent raises it as RosPortError
            self._send(("error", str(exc)))
            return 1
        # Only now: the node's start (rclpy, a DDS participant) ran at normal priority.
        _schedule(stop_only)
        with port:
            self._send(("ready", middleware()))
            threading.Thread(target=self._receive, name="process-child-rx", daemon=True).start()
            try:
                while True:
                    item = self._work.get()
                    if item[0] == "close":
                        break
                    try:
                        self._handle(port, item)
                    except (OSError, EOFError):
                        break  # the parent is gone
            finally:
                # The node's end and the interpreter's at normal priority, as its start
                # (docs/realtime.md).
                leave_realtime_for_process()
        return 0

    def _receive(self) -> None:
        """Take the parent's requests off ``ctl``; answers to ``on_set`` go to their
        waiter, the rest to the main thread, in order."""
        while True:
            try:
                item = self._ctl.recv()
            except (EOFError, OSError):
                self._work.put(("close",))
                return
            if item[0] == "on_set_reply":
                waiter = self._answers.get(item[1])
                if waiter is not None:
                    waiter.put(item[2])
            else:
                self._work.put(item)

    def _handle(self, port: RclpyPort, item: tuple[Any, ...]) -> None:
        op = item[0]
        if op == "pub":
            _, writer_id, cdr = item
            pub = self._writers.get(writer_id)
            if pub is None:
                return
            try:
                # The parent serialized it: published as it is, not turned into a
                # message and serialized again.
                port.publish_serialized(pub, cdr)
            except Exception:
                self.publish_errors += 1
                if self.publish_errors & (self.publish_errors - 1) == 0:
                    logger.exception("publishing on %s failed (%d)", pub.topic, self.publish_errors)
            return
        if op == "close_writer":
            closing = self._writers.pop(item[1], None)
            if closing is not None:
                closing.close()
            return
        if op == "close_reader":
            sub = self._readers.pop(item[1], None)
            if sub is not None:
                sub.close()
            return
        request_id = item[1]
        try:
            value = self._answer(port, op, request_id, item[2:])
        except ParameterError as exc:
            self._send(("reply", request_id, "parameter", str(exc)))
        except Exception as exc:
            self._send(("reply", request_id, "error", f"{op}: {exc}"))
        else:
            self._send(("reply", request_id, "ok", value))

    def _answer(self, port: RclpyPort, op: str, request_id: int, args: Sequence[Any]) -> Any:
        if op == "writer":
            topic, type_name, qos = args
            self._writers[request_id] = port.publisher(topic, message_type(type_name), qos)
            return request_id
        if op == "reader":
            topic, type_name, qos = args

            def forward(msg: Any) -> None:
                cdr = self._ser.serialize_message(msg)
                with self._msg_lock:
                    self._msg.send(("msg", request_id, cdr))

            self._readers[request_id] = port.subscribe(
                topic, message_type(type_name), forward, qos, lane=self._lane
            )
            return request_id
        if op == "matched":
            return self._writers[args[0]].matched_count()
        if op == "sub_matched":
            return self._readers[args[0]].matched_count()
        if op == "declare":
            specs, values = args
            return port.declare_parameters(specs, self._ask_parent, values)
        if op == "set":
            return port.set_parameters(args[0])
        if op == "get":
            return port.parameters()
        raise ValueError(f"unknown request {op!r}")

    def _ask_parent(self, values: Mapping[str, Any]) -> str | None:
        """``on_set`` of the node: the parent decides."""
        request_id = next(self._ids)
        waiter: queue.Queue[str | None] = queue.Queue()
        self._answers[request_id] = waiter
        try:
            self._send(("on_set", request_id, dict(values)))
            return waiter.get(timeout=REQUEST_TIMEOUT_S)
        except queue.Empty:
            return f"the node did not answer in {REQUEST_TIMEOUT_S:.0f} s"
        except OSError as exc:
            return f"the node is gone ({exc})"
        finally:
            self._answers.pop(request_id, None)


def _schedule(stop_only: bool) -> None:
    """Take this child's priority once its node has started (docs/realtime.md): where
    the parent keeps real time, the STOP child does too, every thread of it, below the
    link it feeds; the publishing child, whose middleware calls may block, stays at
    normal scheduling. The start itself runs at normal priority: at real-time priority
    it would hold the cores above the kernel worker that moves a pty's bytes."""
    set_process_name("rover-stop-lane" if stop_only else "rover-ros-node")
    parent_realtime = os.environ.get(PARENT_REALTIME_ENV) == "1"
    priority = STOP_CHILD_PRIORITY if stop_only and parent_realtime else 0
    apply_realtime_to_process(RealtimeConfig(priority, lock_memory=False))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: ``NAME=FD`` arguments for ``ctl`` and ``msg``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    logging.basicConfig(
        level=logging.WARNING,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
    )
    pairs = [arg.split("=", 1) for arg in (sys.argv[1:] if argv is None else argv)]
    conns = {name: Connection(int(fd)) for name, fd in pairs}
    return Child(conns).run()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

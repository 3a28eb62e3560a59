"""A live Foxglove connection: the ground station's ROS traffic on a Foxglove WebSocket
server (``foxglove-sdk``), with the same topics, types and CDR bytes as the MCAP
recording (:mod:`planner.record.mcaprec`).

:class:`FoxgloveLive` is a tap of the ground station's port and takes each planning, as
the recorder does. The tap only queues; its own thread encodes and logs, so the mission
never waits on a viewer. Loopback only: the server has no token of its own.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from firmware_proto.http.bindpolicy import is_loopback
from planner.plan.orchestrator import MissionResult
from planner.record.mcaprec import gate_messages, msgdef, plain_message, ros_name

__all__ = ["FoxgloveLive"]

logger = logging.getLogger(__name__)


class FoxgloveLive:
    """A Foxglove WebSocket server fed by the ground station, on a loopback ``host`` and
    TCP ``port`` (0: a free one).

    Raises:
        ValueError: ``host`` is not loopback.
        ImportError: ``foxglove-sdk`` is not installed (``pip install 'rover-hil[foxglove]'``).
        RuntimeError: the server cannot start (the port is taken).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765) -> None:
        if not is_loopback(host):
            raise ValueError(
                f"refusing to serve Foxglove on {host!r}: it has no token; bind a loopback "
                "address (and reach it through an SSH tunnel)"
            )
        try:
            import foxglove  # noqa: PLC0415  (an optional dependency)
        except ImportError as exc:
            raise ImportError(
                "the Foxglove connection needs foxglove-sdk: pip install 'rover-hil[foxglove]'"
            ) from exc
        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._server = foxglove.start_server(
            name="rover ground station", host=host, port=port, context=self._context
        )
        self._channels: dict[str, tuple[Any, Any]] = {}  # topic -> (channel, encoder)
        self._queue: queue.SimpleQueue[tuple[int, str, type[Any], Any] | None] = queue.SimpleQueue()
        self._closed = False
        self.logged = 0
        """Messages logged so far."""
        self._thread = threading.Thread(target=self._loop, name="foxglove-live", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """The WebSocket address to open in Foxglove."""
        return f"ws://127.0.0.1:{self.port}"

    def tap(self, direction: str, topic: str, msg: Any) -> None:
        """A :data:`bridge.ros.rosport.Tap`: queue ``msg`` (never blocks)."""
        if not self._closed:
            self._queue.put((time.time_ns(), topic, type(msg), msg))

    def planned(self, mission: MissionResult) -> None:
        """Each attempt's verdict and predicted trajectory (as the recorder writes them)."""
        if self._closed:
            return
        now_ns = time.time_ns()
        for topic, cls, msg in gate_messages(mission, now_ns):
            self._queue.put((now_ns, topic, cls, msg))

    def _channel(self, topic: str, cls: type[Any]) -> tuple[Any, Any]:
        found = self._channels.get(topic)
        if found is None:
            from mcap_ros2._dynamic import serialize_dynamic  # noqa: PLC0415

            name = ros_name(cls)
            text = msgdef(cls)
            schema = self._foxglove.Schema(name=name, encoding="ros2msg", data=text.encode())
            channel = self._foxglove.Channel(
                topic, schema=schema, message_encoding="cdr", context=self._context
            )
            found = (channel, serialize_dynamic(name, text)[name])
            self._channels[topic] = found
        return found

    def _loop(self) -> None:
        errors = 0
        while True:
            item = self._queue.get()
            if item is None:
                return
            t_ns, topic, cls, msg = item
            try:
                channel, encode = self._channel(topic, cls)
                channel.log(encode(plain_message(msg)), log_time=t_ns)
                self.logged += 1
            except Exception:
                errors += 1
                if errors & (errors - 1) == 0:
                    logger.exception("foxglove: cannot log a message on %s", topic)

    def close(self) -> None:
        """Stop the thread and the server (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._thread.join(10.0)
        self._server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

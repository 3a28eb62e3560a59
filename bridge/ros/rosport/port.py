"""The ROS port: one small publish/subscribe interface over several backends.

A :class:`RosPort` is one ROS node's worth of topics, its :class:`Publisher` and
:class:`Subscription` objects; messages are the generated ROS 2 classes
(:mod:`bridge.ros.rosport.msgs` re-exports the ones the product uses).

The contract shared by every backend (names, types, QoS, lanes, taps, callbacks that
raise) is docs/rosport.md, "The interface"; the base class enforces what it can. In
short: callbacks run on a thread of the backend, never on the publisher's; each lane
(:data:`DEFAULT_LANE`, :data:`STOP_LANE`) delivers on its own thread, so callbacks of one
lane never overlap and a STOP callback never queues behind telemetry; after
``Subscription.close()`` or ``RosPort.close()`` returns, no new callback starts for it.

Implementing a backend: subclass :class:`RosPort`, set ``backend``, and fill the hooks

- :meth:`RosPort._open_writer` (must): create the endpoint, return a :class:`Writer`;
- :meth:`RosPort._open_reader` (must): create the endpoint, call
  :meth:`RosPort._deliver` from the backend thread for each message, return a
  :class:`Reader`;
- :meth:`RosPort._run` (must): one lane's loop, on that lane's thread; return once
  :attr:`RosPort._stopping` is set;
- :meth:`RosPort._open_lane`, :meth:`RosPort._wake`, :meth:`RosPort._release` (may).

Call :meth:`RosPort._start` at the end of the subclass's ``__init__``. Everything else
(names, type checks, counting, logging, closing, taps) is done here.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import TracebackType
from typing import Any, ClassVar, Final, Generic, Protocol, TypeVar

from bridge.errors import ParameterError
from bridge.ros.rosport import names
from bridge.ros.rosport.errors import (
    MessageError,
    PortClosedError,
    RosPortError,
    TopicTypeError,
)
from bridge.ros.rosport.names import is_message_type, ros_type_name
from bridge.ros.rosport.parameters import OnSet, ParameterSpec, ParameterValue, check_value
from bridge.ros.rosport.qos import DEFAULT, Qos
from firmware_proto.linkio.clock import WALL, Clock, is_lockstep

__all__ = [
    "DEFAULT_LANE",
    "DEFAULT_NODE_NAME",
    "HISTORY_DEPTH",
    "STOP_LANE",
    "TAP_RECEIVED",
    "TAP_SENT",
    "PortStats",
    "Publisher",
    "Reader",
    "RosPort",
    "Subscription",
    "Tap",
    "Writer",
    "deserialized",
]

logger = logging.getLogger(__name__)

M = TypeVar("M")
Message = Any
"""A message: an instance of a generated ROS 2 message class."""

#: Keep-last depth of every publisher and subscription (ROS 2's default profile).
HISTORY_DEPTH: Final = 10
#: Node name used when the caller gives none.
DEFAULT_NODE_NAME: Final = "rosport"
#: How long ``close()`` waits for the backend thread (a callback may be running).
CLOSE_TIMEOUT_S: Final = 5.0
#: The lane of ordinary callbacks.
DEFAULT_LANE: Final = "default"
#: The lane of callbacks that must never wait behind others (an emergency stop).
STOP_LANE: Final = "stop"
LANES: Final = (DEFAULT_LANE, STOP_LANE)
#: Poll period of ``Publisher.wait_for_subscribers``.
_MATCH_POLL_S: Final = 0.01
#: A tap's ``direction`` for a message the port published, and for one it delivered.
TAP_SENT: Final = "sent"
TAP_RECEIVED: Final = "received"

Tap = Callable[[str, str, Any], object]
"""``tap(direction, topic, msg)``: :data:`TAP_SENT` or :data:`TAP_RECEIVED`, the full topic, the
message; called on the sending or delivering thread, so it must be quick and never block."""


def deserialized(cdr: bytes, msg_type: type[M]) -> M:
    """``cdr`` (serialized as :meth:`Publisher.publish_serialized` takes it) as a message of
    ``msg_type``.

    Raises:
        MessageError: the bytes are not such a message (rclpy's error chained).
    """
    try:
        # rclpy's, installed with the message packages; imported only where it is used.
        msg: M = importlib.import_module("rclpy.serialization").deserialize_message(cdr, msg_type)
    except Exception as exc:
        raise MessageError(
            f"{len(cdr)} bytes are not a serialized {ros_type_name(msg_type)}: {exc}"
        ) from exc
    return msg


class Writer(Protocol):
    """What a backend returns from ``_open_writer``: the endpoint behind a Publisher."""

    def write(self, msg: Message) -> None:
        """Send one message (already type-checked). May raise the backend's errors."""

    def matched_count(self) -> int:
        """How many subscriptions currently receive from this endpoint."""

    def close(self) -> None:
        """Delete the endpoint. Called once."""


class Reader(Protocol):
    """What a backend returns from ``_open_reader``: the endpoint behind a Subscription."""

    def matched_count(self) -> int:
        """How many publishers this endpoint currently receives from."""

    def close(self) -> None:
        """Delete the endpoint; deliver nothing more. Called once."""


@dataclass(frozen=True)
class PortStats:
    """Counters of one port since it opened.

    Attributes:
        published: messages handed to the backend by this port's publishers.
        delivered: callbacks that returned normally.
        callback_errors: callbacks that raised.
        dropped: messages discarded because a subscription's keep-last queue was full
            (counted by the in-process backend; DDS and rclpy drop inside their history
            without telling).
    """

    published: int
    delivered: int
    callback_errors: int
    dropped: int


class Publisher(Generic[M]):
    """Publishes messages of one type on one topic. Made by :meth:`RosPort.publisher`."""

    def __init__(
        self, port: RosPort, topic: str, msg_type: type[M], writer: Writer, qos: Qos
    ) -> None:
        self.port = port
        #: The fully qualified topic name.
        self.topic = topic
        self.msg_type = msg_type
        self.qos = qos
        self._writer = writer
        self._closed = False
        self._endpoint_closed = False

    def publish(self, msg: M) -> None:
        """Send ``msg`` to every matched subscription; returns without waiting for them.

        Raises:
            TopicTypeError: ``msg`` is not an instance of this publisher's type.
            PortClosedError: the publisher or its port is closed.
            RosPortError: the backend failed to send (chained to its exception).
        """
        if type(msg) is not self.msg_type:
            raise TopicTypeError(
                f"publisher on {self.topic} sends {self.msg_type.__name__}, "
                f"got {type(msg).__name__}"
            )
        self._send(self._writer.write, msg)
        self.port._tap(TAP_SENT, self.topic, msg)

    def publish_serialized(self, cdr: bytes) -> None:
        """Send ``cdr``, one message of this publisher's type already serialized (CDR with
        its encapsulation header, as ``rclpy.serialization.serialize_message`` makes it),
        without a Python message in between where the backend can: rclpy and the process
        backend send the bytes as they are (unchecked: a subscriber that cannot read them
        drops them), the in-process backend delivers them deserialized. Taps, when the
        port has any, are shown the message deserialized. Built for a hot topic whose
        bytes are packed directly (:mod:`bridge.ros.rosport.cdr`; docs/rosport.md,
        "Serialized messages").

        Raises:
            TypeError: ``cdr`` is not ``bytes``.
            MessageError: the in-process backend could not deserialize ``cdr`` (nothing
                was sent; elsewhere bytes the taps cannot read are sent, and logged).
            PortClosedError: the publisher or its port is closed.
            RosPortError: the backend failed to send (chained to its exception).
        """
        if type(cdr) is not bytes:
            raise TypeError(f"serialized message must be bytes, got {type(cdr).__name__}")
        write = getattr(self._writer, "write_serialized", None)
        if write is None:
            msg = deserialized(cdr, self.msg_type)
            self._send(self._writer.write, msg)
            self.port._tap(TAP_SENT, self.topic, msg)
            return
        self._send(write, cdr)
        if self.port._taps:
            try:
                shown = deserialized(cdr, self.msg_type)
            except MessageError:  # sent: the taps alone miss it
                logger.warning("%s: taps not shown undecodable bytes on %s", self.port, self.topic)
            else:
                self.port._tap(TAP_SENT, self.topic, shown)

    def _send(self, write: Callable[[Any], None], payload: Any) -> None:
        """``write(payload)`` to the backend, counted as published (:meth:`publish`, and
        a backend's publish of serialized bytes).

        Raises:
            PortClosedError: the publisher or its port is closed.
            RosPortError: the backend failed to send (chained to its exception).
        """
        if self._closed or self.port.closed:
            raise PortClosedError(f"publisher on {self.topic} is closed")
        try:
            write(payload)
        except RosPortError:
            raise
        except Exception as exc:
            if self._closed or self.port.closed:
                raise PortClosedError(f"publisher on {self.topic} is closed") from exc
            raise RosPortError(f"publishing on {self.topic} failed: {exc}") from exc
        self.port._count_published()

    def matched_count(self) -> int:
        """How many subscriptions (in any process) currently receive from this publisher."""
        if self._closed or self.port.closed:
            return 0
        return self._writer.matched_count()

    def wait_for_subscribers(self, count: int = 1, timeout_s: float = 5.0) -> bool:
        """Wait until at least ``count`` subscriptions are matched.

        Volatile QoS delivers nothing published before a subscription matched, so a
        sender that must not lose its first messages waits here first.

        Returns:
            True when matched, False when ``timeout_s`` passed first.
        """
        clock = self.port.clock
        deadline = clock.now() + timeout_s
        while self.matched_count() < count:
            remaining = deadline - clock.now()
            if remaining <= 0:
                return False
            clock.sleep(min(_MATCH_POLL_S, remaining))
        return True

    def close(self) -> None:
        """Delete the endpoint. Idempotent; the port closes its publishers too."""
        self._closed = True
        self.port._forget_publisher(self)
        self.port._close_endpoint(self, self._writer)

    @property
    def closed(self) -> bool:
        """True once this publisher or its port is closed."""
        return self._closed or self.port.closed

    def __repr__(self) -> str:
        return f"<Publisher {self.topic} [{ros_type_name(self.msg_type)}]>"


class Subscription(Generic[M]):
    """Calls ``callback(msg)`` for each message on one topic. Made by :meth:`RosPort.subscribe`."""

    def __init__(
        self,
        port: RosPort,
        topic: str,
        msg_type: type[M],
        callback: Callable[[M], object],
        qos: Qos = DEFAULT,
        lane: str = DEFAULT_LANE,
        serialized: bool = False,
    ) -> None:
        self.port = port
        #: The fully qualified topic name.
        self.topic = topic
        self.msg_type = msg_type
        self.callback = callback
        self.qos = qos
        #: The lane (delivery thread) its callbacks run on.
        self.lane = lane
        #: Whether the callback gets each message serialized (CDR ``bytes``), not a
        #: message (:meth:`RosPort.subscribe`).
        self.serialized = serialized
        #: Callbacks that returned normally.
        self.delivered = 0
        #: Callbacks that raised.
        self.errors = 0
        self._reader: Reader | None = None
        self._closed = False
        self._endpoint_closed = False

    def matched_count(self) -> int:
        """How many publishers (in any process) this subscription currently receives from."""
        reader = self._reader
        if reader is None or self._closed or self.port.closed:
            return 0
        return reader.matched_count()

    def wait_for_publishers(self, count: int = 1, timeout_s: float = 5.0) -> bool:
        """Wait until at least ``count`` publishers are matched; ``False`` after ``timeout_s``.

        Over DDS each side discovers the other on its own, so a sender's wait alone
        leaves a window in which volatile samples are lost; waiting on both sides closes it.
        """
        clock = self.port.clock
        deadline = clock.now() + timeout_s
        while self.matched_count() < count:
            if clock.now() >= deadline or self.closed:
                return False
            clock.sleep(_MATCH_POLL_S)
        return True

    def close(self) -> None:
        """Stop delivering and delete the endpoint. Idempotent."""
        self._closed = True
        self.port._forget_subscription(self)
        if self._reader is not None:
            self.port._close_endpoint(self, self._reader)

    @property
    def closed(self) -> bool:
        """True once this subscription or its port is closed."""
        return self._closed or self.port.closed

    def __repr__(self) -> str:
        return f"<Subscription {self.topic} [{ros_type_name(self.msg_type)}]>"


_P = TypeVar("_P", bound="RosPort")


class RosPort:
    """One ROS node's publishers and subscriptions, over one backend.

    Args:
        namespace: the node's namespace; relative topic names are resolved in it
            (``""`` or ``"/"`` is the root; ``"rover1"`` means ``"/rover1"``).
        node_name: the node's name (for ``~`` names and for what the graph shows).

    Raises:
        RosNameError: the namespace or node name is invalid.
    """

    #: Registry name of the backend (``open_port(backend=...)``).
    backend: ClassVar[str] = ""
    #: Whether serialized messages (:meth:`Publisher.publish_serialized`, ``subscribe(...,
    #: serialized=True)``) pass without a Python message in between: over DDS, yes; the
    #: in-process backend carries messages and converts.
    carries_serialized: ClassVar[bool] = False

    def __init__(self, *, namespace: str = "", node_name: str = DEFAULT_NODE_NAME) -> None:
        self.namespace = names.normalize_namespace(namespace)
        self.node_name = names.validate_node_name(node_name)
        self._lock = threading.Lock()
        self._closed = False
        #: Set when the port is closing: every ``_run`` must return soon after.
        self._stopping = threading.Event()
        self._threads: dict[str, threading.Thread] = {}
        self._lockstep_lanes: set[str] = set()  # lanes open without a thread (lockstep)
        self._running = 0  # lane threads that have not returned yet
        self._released = False
        self._pending_release: tuple[list[Publisher[Any]], list[Subscription[Any]]] | None = None
        self._publishers: list[Publisher[Any]] = []
        self._subscriptions: list[Subscription[Any]] = []
        self._topic_types: dict[str, type[Any]] = {}
        self._published = 0
        self._delivered = 0
        self._callback_errors = 0
        self._dropped = 0
        self._param_specs: dict[str, ParameterSpec] = {}
        self._param_values: dict[str, ParameterValue] = {}
        self._on_set: OnSet | None = None
        self._param_lock = threading.Lock()
        self._taps: tuple[Tap, ...] = ()
        #: What the port's waits go through; a lockstep backend sets a virtual clock before
        #: :meth:`_start` (then no lane has a thread: it delivers on the clock's ticks).
        self.clock: Clock = WALL

    # -- public API -------------------------------------------------------------------

    def resolve(self, topic: str) -> str:
        """The fully qualified name of ``topic`` for this node (see :mod:`names`).

        Raises:
            RosNameError: the name is invalid.
        """
        return names.resolve_topic(topic, namespace=self.namespace, node_name=self.node_name)

    def publisher(self, topic: str, msg_type: type[M], qos: Qos = DEFAULT) -> Publisher[M]:
        """Create a publisher of ``msg_type`` on ``topic`` with ``qos``.

        Raises:
            RosNameError: invalid topic name.
            TopicTypeError: ``msg_type`` is not a message type, or this port already
                uses ``topic`` with another type.
            PortClosedError: the port is closed.
            RosPortError: the backend cannot create the endpoint.
        """
        full = self._claim(topic, msg_type)
        try:
            writer = self._open_writer(full, msg_type, qos)
        except RosPortError:
            raise
        except Exception as exc:
            raise RosPortError(f"cannot create a publisher on {full}: {exc}") from exc
        pub = Publisher(self, full, msg_type, writer, qos)
        with self._lock:
            closed = self._closed
            if not closed:
                self._publishers.append(pub)
        if closed:
            writer.close()
            raise PortClosedError(f"{self!r} is closed")
        logger.debug("%s: publisher on %s [%s] (%s)", self, full, ros_type_name(msg_type), qos)
        return pub

    def subscribe(
        self,
        topic: str,
        msg_type: type[M],
        callback: Callable[[M], object],
        qos: Qos = DEFAULT,
        *,
        lane: str = DEFAULT_LANE,
        serialized: bool = False,
    ) -> Subscription[M]:
        """Call ``callback(msg)`` on ``lane``'s thread for each ``msg_type`` on ``topic``.

        With ``serialized``, ``callback`` gets each message as CDR ``bytes`` (as
        :meth:`Publisher.publish_serialized` takes them) instead: where
        :attr:`carries_serialized`, without a Python message in between (a relay, or a
        reader of a few fields of a hot topic: docs/rosport.md, "Serialized messages");
        elsewhere the backend serializes what it delivers. Taps are shown the message.

        Raises:
            RosNameError: invalid topic name.
            TopicTypeError: ``msg_type`` is not a message type, or this port already
                uses ``topic`` with another type.
            ValueError: ``lane`` is not one of :data:`LANES`.
            PortClosedError: the port is closed.
            RosPortError: the backend cannot create the endpoint.
        """
        if not callable(callback):
            raise TypeError(f"callback must be callable, got {type(callback).__name__}")
        if lane not in LANES:
            raise ValueError(f"unknown lane {lane!r}; lanes: {', '.join(LANES)}")
        full = self._claim(topic, msg_type)
        self._ensure_lane(lane)
        sub = Subscription(self, full, msg_type, callback, qos, lane, serialized)
        with self._lock:
            if self._closed:
                raise PortClosedError(f"{self!r} is closed")
            self._subscriptions.append(sub)
        try:
            reader = self._open_reader(sub)
        except Exception as exc:
            self._forget_subscription(sub)
            sub._closed = True
            if isinstance(exc, RosPortError):
                raise
            raise RosPortError(f"cannot subscribe to {full}: {exc}") from exc
        with self._lock:
            sub._reader = reader
            late = self._released  # released implies closed
        if late:
            # The port closed while the endpoint was being made; nobody else will free it.
            self._close_endpoint(sub, reader)
            raise PortClosedError(f"{self!r} is closed")
        logger.debug(
            "%s: subscription on %s [%s] (%s, lane %s)",
            self,
            full,
            ros_type_name(msg_type),
            qos,
            lane,
        )
        return sub

    def add_tap(self, tap: Tap) -> Callable[[], None]:
        """Show ``tap`` every message sent (after the backend took it) and received
        (before the callback) from now on, on that thread (see :data:`Tap`). A tap that
        raises is logged and does not stop the message. Returns a function that removes
        the tap (idempotent)."""
        with self._lock:
            self._taps = (*self._taps, tap)

        def remove() -> None:
            with self._lock:
                self._taps = tuple(t for t in self._taps if t is not tap)

        return remove

    def declare_parameters(
        self, specs: list[ParameterSpec], on_set: OnSet, initial: Mapping[str, Any] | None = None
    ) -> dict[str, ParameterValue]:
        """Declare this node's parameters (:mod:`bridge.ros.rosport.parameters`).

        Args:
            on_set: called with every later change that passed the checks; returns
                ``None`` when applied, or the reason to refuse it.
            initial: values to start with instead of the specs' defaults (what the node
                resolved from its command line, environment and files).

        Returns:
            The values in effect, by name: ``initial``, else the defaults (ROS arguments
            are not applied again here: the node resolved them into ``initial``).

        Raises:
            ParameterError: a value given at start is of the wrong type or out of range.
        """
        values = {spec.name: (initial or {}).get(spec.name, spec.default) for spec in specs}
        declared = self._declare_parameters(specs, values)
        with self._param_lock:
            self._param_specs = {spec.name: spec for spec in specs}
            self._param_values = dict(declared)
            self._on_set = on_set
        return declared

    def set_parameters(self, values: Mapping[str, Any]) -> str | None:
        """Change parameters as ``ros2 param set`` would: all or none.

        Returns:
            ``None`` when applied, else why they were refused (unknown name, read-only,
            wrong type, out of range, or the node's own reason).
        """
        return self._set_parameters(dict(values))

    def parameters(self) -> dict[str, ParameterValue]:
        """The declared parameters' current values, by name."""
        return self._get_parameters()

    def stats(self) -> PortStats:
        """A snapshot of this port's counters."""
        with self._lock:
            return PortStats(self._published, self._delivered, self._callback_errors, self._dropped)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        return self._closed

    @property
    def failure(self) -> str | None:
        """Why the backend stopped working without being closed (its process died); else
        ``None``. A node that cannot work without ROS checks it and exits."""
        return None

    def close(self) -> None:
        """Close every publisher and subscription, stop the lane threads, free the backend.

        Idempotent. Called from a callback (on a lane thread), it returns at once and the
        backend is freed when the callback returns. If a callback is still running after
        ``CLOSE_TIMEOUT_S``, it is logged and the backend is freed when that callback
        returns.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            publishers, self._publishers = self._publishers, []
            subscriptions, self._subscriptions = self._subscriptions, []
            # Whichever of this thread and the lane threads gets there last frees the
            # backend: here after the joins, or the last lane thread when it unwinds.
            self._pending_release = (publishers, subscriptions)
            threads = list(self._threads.values())
        self._stopping.set()
        for sub in subscriptions:
            sub._closed = True
        self._wake()
        current = threading.current_thread()
        deadline = time.monotonic() + CLOSE_TIMEOUT_S
        for thread in threads:
            if thread is not current:
                thread.join(max(0.0, deadline - time.monotonic()))
        busy = [t.name for t in threads if t.is_alive()]
        if busy and busy != [current.name]:
            logger.error(
                "%s: lane thread(s) %s still busy after %.1f s (a callback blocks?); "
                "the last one frees the backend when it returns",
                self,
                ", ".join(busy),
                CLOSE_TIMEOUT_S,
            )
        if not busy:
            self._release_once(publishers, subscriptions)
        logger.debug("%s: closed", self)

    def __enter__(self: _P) -> _P:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        node = self.namespace.rstrip("/") + "/" + self.node_name
        return f"<{type(self).__name__} {node}{' closed' if self._closed else ''}>"

    # -- for backends -----------------------------------------------------------------

    def _start(self) -> None:
        """Start the default lane's thread (call at the end of ``__init__``)."""
        self._ensure_lane(DEFAULT_LANE)

    def _ensure_lane(self, lane: str) -> None:
        """Open ``lane`` and start its thread, once (in lockstep: open it only)."""
        with self._lock:
            if lane in self._threads or lane in self._lockstep_lanes or self._closed:
                return
            self._open_lane(lane)
            if is_lockstep(self.clock):
                self._lockstep_lanes.add(lane)
                return
            thread = threading.Thread(
                target=self._thread_main,
                args=(lane,),
                name=f"rosport-{self.backend}-{self.node_name}-{lane}",
                daemon=True,
            )
            self._threads[lane] = thread
            self._running += 1
        thread.start()

    def _deliver(self, sub: Subscription[Any], msg: Message) -> None:
        """Run ``sub``'s callback with ``msg`` (from a lane thread); log and count errors."""
        if sub._closed:
            return
        if self._taps and not sub.serialized:
            self._tap(TAP_RECEIVED, sub.topic, msg)
        elif self._taps:
            try:
                shown = deserialized(msg, sub.msg_type)
            except MessageError:
                logger.warning("%s: taps not shown undecodable bytes on %s", self, sub.topic)
            else:
                self._tap(TAP_RECEIVED, sub.topic, shown)
        try:
            sub.callback(msg)
        except Exception:
            sub.errors += 1
            with self._lock:
                self._callback_errors += 1
            # Traceback at failures 1, 2, 4, 8, ...: a callback failing on every message
            # must not flood the log.
            if sub.errors & (sub.errors - 1) == 0:
                logger.error(
                    "%s: callback on %s raised (failure %d of this subscription)",
                    self,
                    sub.topic,
                    sub.errors,
                    exc_info=sub.errors == 1,
                )
        else:
            sub.delivered += 1
            with self._lock:
                self._delivered += 1

    def _tap(self, direction: str, topic: str, msg: Message) -> None:
        for tap in self._taps:  # a tuple, replaced whole: no lock on the message path
            try:
                tap(direction, topic, msg)
            except Exception:
                logger.exception("%s: a tap failed on %s", self, topic)

    def _count_dropped(self, count: int = 1) -> None:
        with self._lock:
            self._dropped += count

    def _declare_parameters(
        self, specs: list[ParameterSpec], values: dict[str, ParameterValue]
    ) -> dict[str, ParameterValue]:
        """Declare ``specs`` with ``values``; return the values in effect (default: kept
        here, checked with :func:`check_value`)."""
        for spec in specs:
            reason = check_value(spec, values[spec.name])
            if reason is not None:
                raise ParameterError(f"parameter {reason}")
        return values

    def _set_parameters(self, values: dict[str, Any]) -> str | None:
        """Check and apply a change (default: the checks rclpy makes, then ``on_set``)."""
        with self._param_lock:
            specs, on_set = self._param_specs, self._on_set
            for name, value in values.items():
                spec = specs.get(name)
                if spec is None:
                    return f"parameter {name!r} is not declared"
                if spec.read_only:
                    return f"parameter {name!r} is read-only: set it when the node starts"
                reason = check_value(spec, value)
                if reason is not None:
                    return reason
            reason = on_set(values) if on_set is not None else None
            if reason is None:
                self._param_values.update(values)
            return reason

    def _get_parameters(self) -> dict[str, ParameterValue]:
        """The current values (default: kept here)."""
        with self._param_lock:
            return dict(self._param_values)

    def _open_writer(self, topic: str, msg_type: type[Any], qos: Qos) -> Writer:
        raise NotImplementedError

    def _open_reader(self, sub: Subscription[Any]) -> Reader:
        raise NotImplementedError

    def _open_lane(self, lane: str) -> None:
        """Prepare ``lane`` before its thread starts (default: nothing; lock held): once
        per lane, :data:`DEFAULT_LANE` from :meth:`_start`, the others on first use."""

    def _run(self, lane: str) -> None:
        raise NotImplementedError

    def _wake(self) -> None:
        """Make every :meth:`_run` see :attr:`_stopping` promptly (default: nothing)."""

    def _release(self) -> None:
        """Free the backend's resources (default: nothing). Called once, after every
        lane's ``_run`` has returned."""

    # -- internals --------------------------------------------------------------------

    def _claim(self, topic: str, msg_type: type[Any]) -> str:
        if not is_message_type(msg_type):
            raise TopicTypeError(f"{msg_type!r} is not a generated ROS 2 message class")
        full = self.resolve(topic)
        with self._lock:
            if self._closed:
                raise PortClosedError(f"{self!r} is closed")
            known = self._topic_types.setdefault(full, msg_type)
        if known is not msg_type:
            raise TopicTypeError(
                f"{full} is already used with {ros_type_name(known)} in this port, "
                f"not {ros_type_name(msg_type)}"
            )
        return full

    def _count_published(self) -> None:
        with self._lock:
            self._published += 1

    def _forget_publisher(self, pub: Publisher[M]) -> None:
        with self._lock:
            if pub in self._publishers:
                self._publishers.remove(pub)

    def _forget_subscription(self, sub: Subscription[M]) -> None:
        with self._lock:
            if sub in self._subscriptions:
                self._subscriptions.remove(sub)

    def _close_endpoint(
        self, owner: Publisher[M] | Subscription[M], endpoint: Writer | Reader
    ) -> None:
        with self._lock:
            if owner._endpoint_closed:
                return
            owner._endpoint_closed = True
        try:
            endpoint.close()
        except Exception:
            logger.exception("%s: closing the endpoint of %r failed", self, owner)

    def _thread_main(self, lane: str) -> None:
        try:
            self._run(lane)
        except Exception:
            logger.exception("%s: lane %s failed; it delivers nothing more", self, lane)
        finally:
            with self._lock:
                self._running -= 1
                last = self._running == 0
                pending = self._pending_release
            if last and self._stopping.is_set() and pending is not None:
                self._release_once(*pending)

    def _release_once(
        self, publishers: list[Publisher[Any]], subscriptions: list[Subscription[Any]]
    ) -> None:
        with self._lock:
            if self._released:
                return
            self._released = True
        for pub in publishers:
            pub._closed = True
            self._close_endpoint(pub, pub._writer)
        for sub in subscriptions:
            with self._lock:
                reader = sub._reader
            if reader is not None:
                self._close_endpoint(sub, reader)
        try:
            self._release()
        except Exception:
            logger.exception("%s: releasing the backend failed", self)

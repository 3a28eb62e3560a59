"""The ROS port: one small publish/subscribe interface over several backends.

A :class:`RosPort` is one ROS node's worth of topics. ``publisher(topic, type)`` gives a
:class:`Publisher`; ``subscribe(topic, type, callback)`` gives a :class:`Subscription`;
``close()`` ends everything (idempotent; the port is also a context manager). Messages
are the frozen dataclasses of :mod:`bridge.rosport.msgs`.

Contract shared by every backend (the base class enforces what it can):

- Topic names resolve as ROS 2 does (see :mod:`bridge.rosport.names`): relative names get
  the port's namespace, absolute ones do not; invalid names raise :class:`RosNameError`.
- QoS is ROS 2's default profile: reliable, volatile, keep-last :data:`HISTORY_DEPTH`.
- Callbacks run on a thread of the backend, never on the thread that called
  ``publish``; one port delivers on one thread, so its callbacks never run concurrently
  with each other. A callback that raises is logged and counted (:meth:`RosPort.stats`,
  :attr:`Subscription.errors`) and delivery goes on.
- After ``Subscription.close()`` or ``RosPort.close()`` returns, no new callback starts
  for it (one already running on the backend thread may finish).

Implementing a backend: subclass :class:`RosPort`, set ``backend``, and fill the hooks

- :meth:`RosPort._open_writer` (must): create the endpoint, return a :class:`Writer`;
- :meth:`RosPort._open_reader` (must): create the endpoint, call
  :meth:`RosPort._deliver` from the backend thread for each message, return a
  :class:`Reader`;
- :meth:`RosPort._run` (must): the backend thread's loop; return once
  :attr:`RosPort._stopping` is set;
- :meth:`RosPort._wake` (may): make ``_run`` notice ``_stopping`` at once;
- :meth:`RosPort._release` (may): free what the backend holds; called once, after
  ``_run`` has returned.

Call :meth:`RosPort._start` at the end of the subclass's ``__init__``. Everything else
(names, type checks, counting, logging, closing) is done here.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any, ClassVar, Final, Generic, Protocol, TypeVar

from bridge.rosport import names
from bridge.rosport.errors import PortClosedError, RosPortError, TopicTypeError
from bridge.rosport.msgs import Message

__all__ = [
    "DEFAULT_NODE_NAME",
    "HISTORY_DEPTH",
    "PortStats",
    "Publisher",
    "Reader",
    "RosPort",
    "Subscription",
    "Writer",
]

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

#: Keep-last depth of every publisher and subscription (ROS 2's default profile).
HISTORY_DEPTH: Final = 10
#: Node name used when the caller gives none.
DEFAULT_NODE_NAME: Final = "rosport"
#: How long ``close()`` waits for the backend thread (a callback may be running).
CLOSE_TIMEOUT_S: Final = 5.0
#: Poll period of ``Publisher.wait_for_subscribers``.
_MATCH_POLL_S: Final = 0.01


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

    def __init__(self, port: RosPort, topic: str, msg_type: type[M], writer: Writer) -> None:
        self.port = port
        #: The fully qualified topic name.
        self.topic = topic
        self.msg_type = msg_type
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
        if type(msg) is not self.msg_type and not isinstance(msg, self.msg_type):
            raise TopicTypeError(
                f"publisher on {self.topic} sends {self.msg_type.__name__}, "
                f"got {type(msg).__name__}"
            )
        if self._closed or self.port.closed:
            raise PortClosedError(f"publisher on {self.topic} is closed")
        try:
            self._writer.write(msg)
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
        deadline = time.monotonic() + timeout_s
        waiter = threading.Event()
        while self.matched_count() < count:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            waiter.wait(min(_MATCH_POLL_S, remaining))
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
        return f"<Publisher {self.topic} [{self.msg_type.ROS_TYPE}]>"


class Subscription(Generic[M]):
    """Calls ``callback(msg)`` for each message on one topic. Made by :meth:`RosPort.subscribe`."""

    def __init__(
        self, port: RosPort, topic: str, msg_type: type[M], callback: Callable[[M], object]
    ) -> None:
        self.port = port
        #: The fully qualified topic name.
        self.topic = topic
        self.msg_type = msg_type
        self.callback = callback
        #: Callbacks that returned normally.
        self.delivered = 0
        #: Callbacks that raised.
        self.errors = 0
        self._reader: Reader | None = None
        self._closed = False
        self._endpoint_closed = False

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
        return f"<Subscription {self.topic} [{self.msg_type.ROS_TYPE}]>"


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

    def __init__(self, *, namespace: str = "", node_name: str = DEFAULT_NODE_NAME) -> None:
        self.namespace = names.normalize_namespace(namespace)
        self.node_name = names.validate_node_name(node_name)
        self._lock = threading.Lock()
        self._closed = False
        #: Set when the port is closing: ``_run`` must return soon after.
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._released = False
        self._pending_release: tuple[list[Publisher[Any]], list[Subscription[Any]]] | None = None
        self._publishers: list[Publisher[Any]] = []
        self._subscriptions: list[Subscription[Any]] = []
        self._topic_types: dict[str, type[Message]] = {}
        self._published = 0
        self._delivered = 0
        self._callback_errors = 0
        self._dropped = 0

    # -- public API -------------------------------------------------------------------

    def resolve(self, topic: str) -> str:
        """The fully qualified name of ``topic`` for this node (see :mod:`names`).

        Raises:
            RosNameError: the name is invalid.
        """
        return names.resolve_topic(topic, namespace=self.namespace, node_name=self.node_name)

    def publisher(self, topic: str, msg_type: type[M]) -> Publisher[M]:
        """Create a publisher of ``msg_type`` on ``topic``.

        Raises:
            RosNameError: invalid topic name.
            TopicTypeError: ``msg_type`` is not a message type, or this port already
                uses ``topic`` with another type.
            PortClosedError: the port is closed.
            RosPortError: the backend cannot create the endpoint.
        """
        full = self._claim(topic, msg_type)
        try:
            writer = self._open_writer(full, msg_type)
        except RosPortError:
            raise
        except Exception as exc:
            raise RosPortError(f"cannot create a publisher on {full}: {exc}") from exc
        pub = Publisher(self, full, msg_type, writer)
        with self._lock:
            closed = self._closed
            if not closed:
                self._publishers.append(pub)
        if closed:
            writer.close()
            raise PortClosedError(f"{self!r} is closed")
        logger.debug("%s: publisher on %s [%s]", self, full, msg_type.ROS_TYPE)
        return pub

    def subscribe(
        self, topic: str, msg_type: type[M], callback: Callable[[M], object]
    ) -> Subscription[M]:
        """Call ``callback(msg)`` on the backend thread for each ``msg_type`` on ``topic``.

        Raises:
            RosNameError: invalid topic name.
            TopicTypeError: ``msg_type`` is not a message type, or this port already
                uses ``topic`` with another type.
            PortClosedError: the port is closed.
            RosPortError: the backend cannot create the endpoint.
        """
        if not callable(callback):
            raise TypeError(f"callback must be callable, got {type(callback).__name__}")
        full = self._claim(topic, msg_type)
        sub = Subscription(self, full, msg_type, callback)
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
        logger.debug("%s: subscription on %s [%s]", self, full, msg_type.ROS_TYPE)
        return sub

    def stats(self) -> PortStats:
        """A snapshot of this port's counters."""
        with self._lock:
            return PortStats(self._published, self._delivered, self._callback_errors, self._dropped)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        return self._closed

    def close(self) -> None:
        """Close every publisher and subscription, stop the backend thread, free the backend.

        Idempotent. Called from a callback (on the backend thread), it returns at once
        and the backend is freed when the callback returns. If a callback is still
        running after ``CLOSE_TIMEOUT_S``, it is logged and the backend is freed when
        that callback returns.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            publishers, self._publishers = self._publishers, []
            subscriptions, self._subscriptions = self._subscriptions, []
            # Whichever of this thread and the backend thread gets there last frees the
            # backend: here after the join, or the backend thread when it unwinds.
            self._pending_release = (publishers, subscriptions)
        self._stopping.set()
        for sub in subscriptions:
            sub._closed = True
        self._wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(CLOSE_TIMEOUT_S)
            if thread.is_alive():
                logger.error(
                    "%s: backend thread still busy after %.1f s (a callback blocks?); "
                    "it frees the backend when it returns",
                    self,
                    CLOSE_TIMEOUT_S,
                )
        if thread is None or not thread.is_alive():
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
        """Start the backend thread running :meth:`_run` (call at the end of ``__init__``)."""
        thread = threading.Thread(
            target=self._thread_main, name=f"rosport-{self.backend}-{self.node_name}", daemon=True
        )
        self._thread = thread
        thread.start()

    def _deliver(self, sub: Subscription[Any], msg: Message) -> None:
        """Run ``sub``'s callback with ``msg`` (from the backend thread); log and count errors."""
        if sub._closed:
            return
        try:
            sub.callback(msg)
        except Exception:
            sub.errors += 1
            with self._lock:
                self._callback_errors += 1
            # The first failure with its traceback, then at 2, 4, 8, ... so a callback
            # that fails on every message cannot flood the log.
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

    def _count_dropped(self, count: int = 1) -> None:
        with self._lock:
            self._dropped += count

    def _open_writer(self, topic: str, msg_type: type[Message]) -> Writer:
        raise NotImplementedError

    def _open_reader(self, sub: Subscription[Any]) -> Reader:
        raise NotImplementedError

    def _run(self) -> None:
        raise NotImplementedError

    def _wake(self) -> None:
        """Make :meth:`_run` see :attr:`_stopping` promptly (default: nothing)."""

    def _release(self) -> None:
        """Free the backend's resources (default: nothing). Called once, after ``_run``."""

    # -- internals --------------------------------------------------------------------

    def _claim(self, topic: str, msg_type: type[Message]) -> str:
        if not (isinstance(msg_type, type) and issubclass(msg_type, Message)):
            raise TopicTypeError(f"{msg_type!r} is not a message type of bridge.rosport.msgs")
        full = self.resolve(topic)
        with self._lock:
            if self._closed:
                raise PortClosedError(f"{self!r} is closed")
            known = self._topic_types.setdefault(full, msg_type)
        if known is not msg_type:
            raise TopicTypeError(
                f"{full} is already used with {known.ROS_TYPE} in this port, "
                f"not {msg_type.ROS_TYPE}"
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

    def _thread_main(self) -> None:
        try:
            self._run()
        except Exception:
            logger.exception("%s: backend thread failed; the port delivers nothing more", self)
        finally:
            pending = self._pending_release
            if self._stopping.is_set() and pending is not None:
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

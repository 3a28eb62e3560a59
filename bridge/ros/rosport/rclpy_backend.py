"""The ``rclpy`` backend: a real ROS 2 node (production, on Jazzy).

Importing this module never needs ROS: rclpy is imported when a port opens, and a machine
without it gets :class:`BackendUnavailableError` saying how to install it. This is the
only module of the project that imports rclpy itself (message classes come from
:mod:`bridge.ros.rosport.msgs`).

A port is one rclpy node in its own context, without rclpy's signal handlers. Each lane's
thread waits on an rcl wait set of its own (through
``rclpy.impl.implementation_singleton``) and takes its messages itself. The default lane's
set also holds the node's services, timers, clients and waitables, whose callbacks a
``SingleThreadedExecutor`` runs on that same thread. The STOP lane is a second node
``<node_name>_stop`` whose set holds the STOP subscriptions alone, so an emergency stop
waits for no other callback (docs/rosport.md, "``rclpy``"). Messages are published and
delivered as they are.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import threading
from collections.abc import Sequence
from typing import Any, Final

from bridge.errors import ParameterError
from bridge.ros.rosport.discovery import use_fast_discovery
from bridge.ros.rosport.errors import BackendUnavailableError, RosPortError
from bridge.ros.rosport.parameters import ParameterSpec, ParameterValue
from bridge.ros.rosport.port import (
    DEFAULT_LANE,
    DEFAULT_NODE_NAME,
    Message,
    Publisher,
    RosPort,
    Subscription,
)
from bridge.ros.rosport.qos import Qos

__all__ = ["STOP_NODE_SUFFIX", "RclpyPort", "middleware", "rclpy_available"]

logger = logging.getLogger(__name__)

_MAX_DESTROYED_SPINS: Final = 100
"""Spins in a row that may meet an entity being destroyed before the lane fails."""

#: Executor spin period: each lane re-checks for close at least this often, s.
_SPIN_S: Final = 0.5
#: The STOP lane's node is named ``<node_name>`` + this.
STOP_NODE_SUFFIX: Final = "_stop"


def rclpy_available() -> bool:
    """True when rclpy and the message packages can be imported here."""
    try:
        importlib.import_module("rclpy")
        importlib.import_module("std_msgs.msg")
    except ImportError:
        return False
    return True


def _import_rclpy() -> Any:
    try:
        return importlib.import_module("rclpy")
    except ImportError as exc:
        raise BackendUnavailableError(
            "the 'rclpy' ROS port backend needs ROS 2 Jazzy (rclpy), which is not installed "
            "here: install this project with its 'ros' extra (pip install 'rover-hil[ros]') "
            f"or source /opt/ros/jazzy/setup.bash before starting ({exc})"
        ) from exc


def middleware() -> str:
    """The ROS 2 middleware rclpy uses here and rclpy's version, e.g.
    ``"rmw_fastrtps_cpp (rclpy 7.1.6)"``.

    Raises:
        BackendUnavailableError: rclpy is not installed.
    """
    _import_rclpy()
    rmw = importlib.import_module("rclpy.utilities").get_rmw_implementation_identifier()
    try:
        version = importlib.import_module("importlib.metadata").version("ros-rclpy")
    except Exception:  # a system ROS 2 (apt) has no Python distribution metadata
        version = "system"
    return f"{rmw} (rclpy {version})"


class _Writer:
    def __init__(self, node: Any, publisher: Any) -> None:
        self._node = node
        self._publisher = publisher

    def write(self, msg: Message) -> None:
        self._publisher.publish(msg)

    def write_serialized(self, cdr: bytes) -> None:
        self._publisher.publish(cdr)  # rclpy publishes bytes as they are (publish_raw)

    def matched_count(self) -> int:
        return int(self._publisher.get_subscription_count())

    def close(self) -> None:
        self._node.destroy_publisher(self._publisher)


class _Reader:
    def __init__(self, lane: _Lane, subscription: Any) -> None:
        self._lane = lane
        self._subscription = subscription

    def matched_count(self) -> int:
        return int(self._subscription.get_publisher_count())

    def close(self) -> None:
        with self._lane.lock:
            self._lane.readers = [r for r in self._lane.readers if r[0] is not self._subscription]
        self._lane.guard.trigger()
        self._lane.node.destroy_subscription(self._subscription)


class _Lane:
    """One lane: a node, the executor of its node's other entities (``None`` on the STOP
    lane, which waits on its subscriptions alone), a guard condition that wakes it, and
    the subscriptions the loop takes from."""

    def __init__(self, node: Any, executor: Any) -> None:
        self.node = node
        self.executor = executor
        self.guard = node.create_guard_condition(lambda: None)
        self.lock = threading.Lock()
        self.readers: list[tuple[Any, Subscription[Any]]] = []


class _NodeEntities:
    """The node's entities other than subscriptions that a default lane waits on."""

    __slots__ = ("clients", "services", "timers", "waitables")

    def __init__(
        self,
        services: tuple[Any, ...],
        timers: tuple[Any, ...],
        clients: tuple[Any, ...],
        waitables: tuple[Any, ...],
    ) -> None:
        self.services = services
        self.timers = timers
        self.clients = clients
        self.waitables = waitables

    def __eq__(self, other: object) -> bool:
        """The same entities (compared by identity, as rclpy's entities are)."""
        return isinstance(other, _NodeEntities) and (
            self.services,
            self.timers,
            self.clients,
            self.waitables,
        ) == (other.services, other.timers, other.clients, other.waitables)

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def of(cls, node: Any) -> _NodeEntities:
        """The node's entities now (none for ``None``: the STOP lane waits on none)."""
        if node is None:
            return _NO_ENTITIES
        return cls(
            tuple(node.services), tuple(node.timers), tuple(node.clients), tuple(node.waitables)
        )


_NO_ENTITIES: Final = _NodeEntities((), (), (), ())


class _LaneWait:
    """An rcl wait set for one lane, and the rcl handles it holds while it exists.

    Held handles cannot be destroyed under the wait: an entity closed on another thread is
    destroyed when :meth:`close` lets go of it (the lane's guard wakes the lane to build
    a new wait set without it).

    Raises:
        InvalidHandle: (rclpy's) an entity was destroyed before it could be held.
    """

    def __init__(
        self,
        rcl: Any,
        context: Any,
        lane: _Lane,
        readers: tuple[tuple[Any, Subscription[Any]], ...],
        entities: _NodeEntities,
    ) -> None:
        self._readers = readers
        self._entities = entities
        self._guard = lane.guard
        self._held = contextlib.ExitStack()
        try:
            self._held.enter_context(context.handle)
            self._held.enter_context(lane.guard.handle)
            for entity in (
                *(r[0] for r in readers),
                *entities.services,
                *entities.timers,
                *entities.clients,
            ):
                self._held.enter_context(entity.handle)
            counts = [len(readers), 1, len(entities.timers), len(entities.clients)]
            counts += [len(entities.services), 0]
            for waitable in entities.waitables:  # a waitable may hold entities of every kind
                self._held.enter_context(waitable)
                n = waitable.get_num_entities()
                extra = (
                    n.num_subscriptions,
                    n.num_guard_conditions,
                    n.num_timers,
                    n.num_clients,
                    n.num_services,
                    n.num_events,
                )
                counts = [a + b for a, b in zip(counts, extra, strict=True)]
            self._wait_set = rcl.WaitSet(*counts, context.handle)
        except BaseException:
            self._held.close()
            raise

    def holds(
        self, readers: tuple[tuple[Any, Subscription[Any]], ...], entities: _NodeEntities
    ) -> bool:
        """True while the lane's entities are the ones this wait set was built for."""
        return entities == self._entities and readers == self._readers

    def wait(self, timeout_ns: int) -> tuple[list[tuple[Subscription[Any], Any]], int]:
        """Wait at most ``timeout_ns`` for any entity, then take the ready messages.

        Returns:
            The messages taken from ready subscriptions, in reader order, and how many of
            the node's other entities are ready (their callbacks are the executor's).
        """
        ws = self._wait_set
        e = self._entities
        ws.clear_entities()  # rcl_wait leaves only the ready entities in the set
        for subscription, _ in self._readers:
            ws.add_subscription(subscription.handle)
        ws.add_guard_condition(self._guard.handle)
        for timer in e.timers:
            ws.add_timer(timer.handle)
        for client in e.clients:
            ws.add_client(client.handle)
        for service in e.services:
            ws.add_service(service.handle)
        for waitable in e.waitables:
            waitable.add_to_wait_set(ws)
        ws.wait(timeout_ns)
        taken: list[tuple[Subscription[Any], Any]] = []
        for index, (subscription, sub) in enumerate(self._readers):
            if ws.is_ready("subscription", index):
                message = subscription.handle.take_message(sub.msg_type, sub.serialized)
                if message is not None:
                    taken.append((sub, message[0]))
        others = 0
        for kind, count in (
            ("timer", len(e.timers)),
            ("client", len(e.clients)),
            ("service", len(e.services)),
        ):
            others += sum(1 for index in range(count) if ws.is_ready(kind, index))
        others += sum(1 for waitable in e.waitables if waitable.is_ready(ws))
        return taken, others

    def close(self) -> None:
        """Let go of the held handles (entities closed meanwhile are destroyed now)."""
        self._held.close()


class RclpyPort(RosPort):
    """A port that is an rclpy node (``open_port("rclpy", ...)``).

    Args:
        namespace, node_name: see :class:`RosPort` (also the node's).
        domain_id: ROS domain; default ``$ROS_DOMAIN_ID``, else 0.
        args: ROS command-line arguments for this context (``["--ros-args", ...]``):
            remappings, ``-p`` parameters, ``--params-file``, log levels.
        stop_only: a node that only takes the STOP lane's subscriptions (the STOP child
            of :mod:`bridge.ros.rosport.process_backend`): the node itself is the STOP lane's,
            waited on by the lane's rcl wait set; no executor, no second node, no
            parameter services.

    Raises:
        BackendUnavailableError: rclpy or a message package is not installed.
        RosPortError: rclpy failed to create the context or node.
    """

    backend = "rclpy"
    carries_serialized = True

    def __init__(
        self,
        *,
        namespace: str = "",
        node_name: str = DEFAULT_NODE_NAME,
        domain_id: int | None = None,
        args: Sequence[str] = (),
        stop_only: bool = False,
    ) -> None:
        super().__init__(namespace=namespace, node_name=node_name)
        self._stop_only = stop_only
        use_fast_discovery()  # before the process's first participant (discovery.py)
        rclpy = _import_rclpy()
        # Imported here, not at the top: this module must import where ROS is absent.
        self._qos_mod = importlib.import_module("rclpy.qos")
        self._executors = importlib.import_module("rclpy.executors")
        signals = importlib.import_module("rclpy.signals")
        self._node_cls = importlib.import_module("rclpy.node").Node
        self._context = importlib.import_module("rclpy.context").Context()
        self._lanes: dict[str, _Lane] = {}
        self._lanes_lock = threading.Lock()
        try:
            rclpy.init(
                args=list(args),
                context=self._context,
                domain_id=domain_id,
                signal_handler_options=signals.SignalHandlerOptions.NO,
            )
            if stop_only:
                self._node = self._node_cls(
                    node_name,
                    namespace=self.namespace,
                    context=self._context,
                    start_parameter_services=False,
                    enable_rosout=False,
                )
            else:
                self._node = self._node_cls(
                    node_name, namespace=self.namespace, context=self._context
                )
        except Exception as exc:
            self._context.try_shutdown()
            raise RosPortError(f"cannot start an rclpy node {node_name!r}: {exc}") from exc
        self._start()

    @property
    def node(self) -> Any:
        """The rclpy node (parameters, timers, services: what this port does not wrap)."""
        return self._node

    def _profile(self, qos: Qos) -> Any:
        q = self._qos_mod
        return q.QoSProfile(
            history=q.HistoryPolicy.KEEP_LAST,
            depth=qos.depth,
            reliability=(
                q.ReliabilityPolicy.RELIABLE if qos.reliable else q.ReliabilityPolicy.BEST_EFFORT
            ),
            durability=(
                q.DurabilityPolicy.TRANSIENT_LOCAL
                if qos.transient_local
                else q.DurabilityPolicy.VOLATILE
            ),
        )

    def _open_lane(self, lane: str) -> None:
        try:
            if self._stop_only:  # every lane waits on this node's wait set; none is spun
                node, executor = self._node, None
            elif lane == DEFAULT_LANE:
                node = self._node
                executor = self._executors.SingleThreadedExecutor(context=self._context)
                executor.add_node(node)
            else:
                node = self._node_cls(
                    self.node_name + STOP_NODE_SUFFIX,
                    namespace=self.namespace,
                    context=self._context,
                    start_parameter_services=False,
                    enable_rosout=False,
                )
                executor = None
        except Exception as exc:
            raise RosPortError(f"cannot open the {lane} lane of {self!r}: {exc}") from exc
        with self._lanes_lock:
            self._lanes[lane] = _Lane(node, executor)

    def _lane(self, lane: str) -> _Lane:
        with self._lanes_lock:
            return self._lanes[lane]

    # -- parameters: real ROS 2 parameters of the node ------------------------------------
    def _declare_parameters(
        self, specs: list[ParameterSpec], values: dict[str, ParameterValue]
    ) -> dict[str, ParameterValue]:
        interfaces = importlib.import_module("rcl_interfaces.msg")
        exceptions = importlib.import_module("rclpy.exceptions")
        declared: dict[str, ParameterValue] = {}
        for spec in specs:
            descriptor = interfaces.ParameterDescriptor(
                name=spec.name, description=spec.description, read_only=spec.read_only
            )
            if spec.range is not None and spec.kind is int:
                low, high = spec.range
                descriptor.integer_range = [
                    interfaces.IntegerRange(from_value=int(low), to_value=int(high), step=0)
                ]
            elif spec.range is not None and spec.kind is float:
                low, high = spec.range
                descriptor.floating_point_range = [
                    interfaces.FloatingPointRange(
                        from_value=float(low), to_value=float(high), step=0.0
                    )
                ]
            try:
                # The node resolved its ROS arguments with its other sources, in one order
                # of precedence (bridge.ros.params.load_params): rclpy must not apply them again.
                param = self._node.declare_parameter(
                    spec.name, values[spec.name], descriptor, ignore_override=True
                )
            except (
                exceptions.InvalidParameterValueException,
                exceptions.InvalidParameterTypeException,
            ) as exc:
                raise ParameterError(f"parameter {spec.name} (ROS parameter): {exc}") from exc
            declared[spec.name] = param.value
        self._node.add_on_set_parameters_callback(self._on_set_parameters)
        return declared

    def _on_set_parameters(self, params: list[Any]) -> Any:
        """rclpy's callback, after its own type, range and read-only checks."""
        result = importlib.import_module("rcl_interfaces.msg").SetParametersResult
        with self._param_lock:
            on_set = self._on_set
        reason = on_set({p.name: p.value for p in params}) if on_set is not None else None
        if reason is not None:
            logger.warning("%s: parameters refused: %s", self, reason)
            return result(successful=False, reason=reason)
        return result(successful=True)

    def _set_parameters(self, values: dict[str, Any]) -> str | None:
        parameter = importlib.import_module("rclpy.parameter").Parameter
        try:
            results = self._node.set_parameters_atomically(
                [parameter(name, value=value) for name, value in values.items()]
            )
        except Exception as exc:  # undeclared name, or a value rclpy cannot type
            return f"{', '.join(values)}: {exc}"
        return None if results.successful else f"{', '.join(values)}: {results.reason}"

    def _get_parameters(self) -> dict[str, ParameterValue]:
        with self._param_lock:
            names = list(self._param_specs)
        return {name: self._node.get_parameter(name).value for name in names}

    # -- endpoints --------------------------------------------------------------------------
    def _open_writer(self, topic: str, msg_type: type[Any], qos: Qos) -> _Writer:
        publisher = self._node.create_publisher(msg_type, topic, self._profile(qos))
        return _Writer(self._node, publisher)

    def publish_serialized(self, publisher: Publisher[Any], cdr: bytes) -> None:
        """Publish ``cdr``, a message of ``publisher``'s type already serialized (CDR, as
        ``rclpy.serialization.serialize_message`` makes it), as it is: rclpy's raw publish,
        without turning it into a Python message and back (the ``rclpy-process`` child,
        which gets its parent's messages serialized). Counted as published like
        :meth:`Publisher.publish`; taps are not shown it (they are shown messages, not
        bytes).

        Raises:
            PortClosedError: the publisher or this port is closed.
            RosPortError: ``publisher`` is not this port's, or rclpy failed to send
                (chained to its exception).
        """
        writer = publisher._writer
        if publisher.port is not self or not isinstance(writer, _Writer):
            raise RosPortError(f"publisher on {publisher.topic} is not one of {self!r}")
        publisher._send(writer.write_serialized, cdr)

    def _open_reader(self, sub: Subscription[Any]) -> _Reader:
        lane = self._lane(sub.lane)

        def on_message(msg: Any) -> None:
            self._deliver(sub, msg)

        subscription = lane.node.create_subscription(
            sub.msg_type, sub.topic, on_message, self._profile(sub.qos), raw=sub.serialized
        )
        with lane.lock:
            lane.readers.append((subscription, sub))
        lane.guard.trigger()  # the lane rebuilds its wait set with the new subscription
        return _Reader(lane, subscription)

    def _run(self, lane_name: str) -> None:
        """One lane's loop: an rcl wait set of the lane's subscriptions and its guard.

        Each ready subscription's message is taken here and delivered on this thread. The
        default lane's wait set also holds the node's services, timers, clients and
        waitables (parameter services, QoS events); when one of those is ready the lane's
        executor runs the ready callbacks on this same thread. The wait set and the rcl
        handles it holds are kept from one wait to the next and built again only when the
        entities change. rclpy's own executor rebuilds its whole wait set, with a fresh
        timeout timer, for every message: a subscriber's CPU per message was 1.4-1.9 times
        this loop's (docs/rosport.md, "The default lane's CPU").
        """
        lane = self._lane(lane_name)
        rcl = importlib.import_module("rclpy.impl.implementation_singleton").rclpy_implementation
        timeout_ns = int(_SPIN_S * 1e9)
        destroyed = 0  # builds in a row that met an entity being destroyed
        node = self._node if lane.executor is not None else None
        wait: _LaneWait | None = None
        try:
            while not self._stopping.is_set() and self._context.ok():
                with lane.lock:
                    readers = tuple(lane.readers)
                entities = _NodeEntities.of(node)
                if wait is None or not wait.holds(readers, entities):
                    if wait is not None:
                        wait.close()
                        wait = None
                    try:
                        wait = _LaneWait(rcl, self._context, lane, readers, entities)
                        destroyed = 0
                    except rcl.InvalidHandle:
                        # An entity of this lane closed on another thread while the wait
                        # set was built: the next build is without it. An entity that
                        # stays invalid is a failure of the lane.
                        destroyed += 1
                        if destroyed > _MAX_DESTROYED_SPINS:
                            raise
                        logger.debug("%s: lane %s met an entity being destroyed", self, lane_name)
                        continue
                taken, others_ready = wait.wait(timeout_ns)
                for sub, msg in taken:
                    self._deliver(sub, msg)
                if others_ready and lane.executor is not None:
                    # Each spin runs one ready callback; a spin that finds none returns.
                    for _ in range(others_ready):
                        lane.executor.spin_once(timeout_sec=0)
        finally:
            if wait is not None:
                wait.close()

    def _wake(self) -> None:
        with self._lanes_lock:
            lanes = list(self._lanes.values())
        for lane in lanes:
            try:
                lane.guard.trigger()
            except Exception as exc:  # already destroyed: nothing to wake
                logger.debug("%s: waking a lane: %s", self, exc)

    def _release(self) -> None:
        with self._lanes_lock:
            lanes = list(self._lanes.values())
        for lane in lanes:
            if lane.executor is not None:
                lane.executor.shutdown(timeout_sec=1.0)
            if lane.node is not self._node:
                lane.node.destroy_node()
        self._node.destroy_node()
        self._context.try_shutdown()

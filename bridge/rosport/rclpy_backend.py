"""The ``rclpy`` backend: a real ROS 2 node (production, on Jazzy).

Importing this module never needs ROS: rclpy and the message packages are imported when
a port opens, and a machine without them gets :class:`BackendUnavailableError` saying
so. This is the only module of the project that imports rclpy.

A port is one rclpy node in its own context (``rclpy.init`` with the port's domain and
without signal handlers, so the application keeps its own), spun by a single-threaded
executor on the port's thread. Publishers and subscriptions use the same QoS as every
backend (reliable, volatile, keep-last 10). Our dataclasses are converted field by field
to and from the generated classes of std_msgs, geometry_msgs, nav_msgs,
diagnostic_msgs and builtin_interfaces; a ROS ``byte`` (``DiagnosticStatus.level``)
is an int here and a one-byte ``bytes`` in rclpy.
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any, Final

from bridge.rosport.errors import BackendUnavailableError, RosPortError
from bridge.rosport.msgs import MESSAGE_TYPES, Message, parse_field_type
from bridge.rosport.port import DEFAULT_NODE_NAME, HISTORY_DEPTH, RosPort, Subscription

__all__ = ["RclpyPort", "rclpy_available"]

logger = logging.getLogger(__name__)

#: Executor spin period: the loop re-checks for close at least this often.
_SPIN_S: Final = 0.1

_Convert = Callable[[Any], Any]


def rclpy_available() -> bool:
    """True when rclpy can be imported here (a ROS 2 setup is sourced)."""
    try:
        importlib.import_module("rclpy")
    except ImportError:
        return False
    return True


def _import_rclpy() -> Any:
    try:
        return importlib.import_module("rclpy")
    except ImportError as exc:
        raise BackendUnavailableError(
            "the 'rclpy' ROS port backend needs ROS 2 (rclpy), which is not installed "
            "here: source a ROS 2 Jazzy setup (e.g. /opt/ros/jazzy/setup.bash) before "
            "starting, or use the 'dds' backend, which speaks the same wire format "
            f"without ROS ({exc})"
        ) from exc


class _Converter:
    """Converts one message type to and from its rclpy class, field by field."""

    def __init__(self, msg_type: type[Message]) -> None:
        self.msg_type = msg_type
        package, kind, name = msg_type.ROS_TYPE.split("/")
        try:
            module = importlib.import_module(f"{package}.{kind}")
            self.ros_class: Any = getattr(module, name)
        except (ImportError, AttributeError) as exc:
            raise BackendUnavailableError(
                f"the ROS 2 interface {msg_type.ROS_TYPE} is not installed ({exc})"
            ) from exc
        self._to: list[tuple[str, _Convert]] = []
        self._from: list[tuple[str, _Convert]] = []
        for field_name, ros_field_type in msg_type.ROS_FIELDS:
            element, size = parse_field_type(ros_field_type)
            to_one, from_one = _element_converters(element)
            if size is None:
                self._to.append((field_name, to_one))
                self._from.append((field_name, from_one))
            else:
                self._to.append((field_name, _each(to_one, list)))
                self._from.append((field_name, _each(from_one, tuple)))

    def to_ros(self, msg: Any) -> Any:
        out = self.ros_class()
        for name, convert in self._to:
            setattr(out, name, convert(getattr(msg, name)))
        return out

    def from_ros(self, obj: Any) -> Message:
        return self.msg_type(**{name: convert(getattr(obj, name)) for name, convert in self._from})


_CONVERTERS: dict[type[Message], _Converter] = {}
_CONVERTERS_LOCK = threading.RLock()


def _converter(msg_type: type[Message]) -> _Converter:
    with _CONVERTERS_LOCK:
        conv = _CONVERTERS.get(msg_type)
        if conv is None:
            conv = _CONVERTERS[msg_type] = _Converter(msg_type)
        return conv


def _element_converters(element: str) -> tuple[_Convert, _Convert]:
    if element == "byte":
        return (lambda v: bytes((v,))), (
            lambda v: v[0] if isinstance(v, (bytes, bytearray)) else int(v)
        )
    if element == "char":
        return chr, (lambda v: ord(v) if isinstance(v, str) else int(v))
    if element in ("float32", "float64"):
        return float, float
    if element == "bool":
        return bool, bool
    if element == "string":
        return str, str
    if element in MESSAGE_TYPES:
        nested = MESSAGE_TYPES[element]
        return (lambda v: _converter(nested).to_ros(v)), (lambda v: _converter(nested).from_ros(v))
    return int, int


def _each(convert: _Convert, container: _Convert) -> _Convert:
    def many(values: Any) -> Any:
        return container([convert(v) for v in values])

    return many


class _RclpyWriter:
    def __init__(self, port: RclpyPort, publisher: Any, converter: _Converter) -> None:
        self._port = port
        self._publisher = publisher
        self._converter = converter

    def write(self, msg: Message) -> None:
        self._publisher.publish(self._converter.to_ros(msg))

    def matched_count(self) -> int:
        return int(self._publisher.get_subscription_count())

    def close(self) -> None:
        self._port._node.destroy_publisher(self._publisher)


class _RclpyReader:
    def __init__(self, port: RclpyPort, subscription: Any) -> None:
        self._port = port
        self._subscription = subscription

    def close(self) -> None:
        self._port._node.destroy_subscription(self._subscription)


class RclpyPort(RosPort):
    """A port that is an rclpy node (``open_port("rclpy", ...)``).

    Args:
        namespace: see :class:`RosPort` (also the node's namespace).
        node_name: see :class:`RosPort` (also the node's name).
        domain_id: ROS domain; default ``$ROS_DOMAIN_ID``, else 0.
        args: ROS command-line arguments for this context (``--ros-args ...``).

    Raises:
        BackendUnavailableError: rclpy or a message package is not installed.
        RosPortError: rclpy failed to create the context or node.
    """

    backend = "rclpy"

    def __init__(
        self,
        *,
        namespace: str = "",
        node_name: str = DEFAULT_NODE_NAME,
        domain_id: int | None = None,
        args: Sequence[str] = (),
    ) -> None:
        super().__init__(namespace=namespace, node_name=node_name)
        rclpy = _import_rclpy()
        # Imported here, not at the top: this module must import where ROS is absent.
        executors = importlib.import_module("rclpy.executors")
        qos = importlib.import_module("rclpy.qos")
        signals = importlib.import_module("rclpy.signals")
        Context = importlib.import_module("rclpy.context").Context  # noqa: N806
        Node = importlib.import_module("rclpy.node").Node  # noqa: N806

        self._context = Context()
        try:
            rclpy.init(
                args=list(args),
                context=self._context,
                domain_id=domain_id,
                signal_handler_options=signals.SignalHandlerOptions.NO,
            )
            self._node = Node(node_name, namespace=self.namespace, context=self._context)
            self._executor = executors.SingleThreadedExecutor(context=self._context)
            self._executor.add_node(self._node)
            self._guard = self._node.create_guard_condition(lambda: None)
        except Exception as exc:
            self._context.try_shutdown()
            raise RosPortError(f"cannot start an rclpy node {node_name!r}: {exc}") from exc
        self._qos = qos.QoSProfile(
            history=qos.HistoryPolicy.KEEP_LAST,
            depth=HISTORY_DEPTH,
            reliability=qos.ReliabilityPolicy.RELIABLE,
            durability=qos.DurabilityPolicy.VOLATILE,
        )
        self._start()

    @property
    def node(self) -> Any:
        """The rclpy node (for parameters, timers, services: things this port does not wrap)."""
        return self._node

    def _open_writer(self, topic: str, msg_type: type[Message]) -> _RclpyWriter:
        converter = _converter(msg_type)
        publisher = self._node.create_publisher(converter.ros_class, topic, self._qos)
        return _RclpyWriter(self, publisher, converter)

    def _open_reader(self, sub: Subscription[Message]) -> _RclpyReader:
        converter = _converter(sub.msg_type)

        def on_message(ros_msg: Any) -> None:
            try:
                msg = converter.from_ros(ros_msg)
            except Exception:
                logger.exception("%s: cannot convert a message on %s", self, sub.topic)
                return
            self._deliver(sub, msg)

        subscription = self._node.create_subscription(
            converter.ros_class, sub.topic, on_message, self._qos
        )
        self._guard.trigger()  # the executor rebuilds its wait set with the new subscription
        return _RclpyReader(self, subscription)

    def _run(self) -> None:
        while not self._stopping.is_set() and self._context.ok():
            self._executor.spin_once(timeout_sec=_SPIN_S)

    def _wake(self) -> None:
        self._guard.trigger()

    def _release(self) -> None:
        self._executor.shutdown()
        self._node.destroy_node()
        self._context.try_shutdown()

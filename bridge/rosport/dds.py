"""The ``dds`` backend: Cyclone DDS speaking the ROS 2 wire format, without ROS.

A ROS 2 Jazzy node on rmw_cyclonedds_cpp (or any RMW that follows the same DDS mapping)
sees this port's topics as ROS topics, and this port sees theirs. What makes it so:

- **Topic names**: the fully qualified ROS name prefixed with ``rt``: ``/rover1/odom`` is
  the DDS topic ``rt/rover1/odom``.
- **Type names**: rosidl's DDS mapping, ``<package>::msg::dds_::<Name>_``, for the
  message and for every nested type (``std_msgs::msg::dds_::Header_``, ...); an empty
  message has rosidl's one member ``uint8 structure_needs_at_least_one_member``.
- **Encoding**: final (non-extensible) structs, plain CDR: the DATA_REPRESENTATION QoS
  of every reader and writer is forced to XCDR1, so samples carry the ``CDR_LE``
  encapsulation header ``00 01 00 00`` as rmw_cyclonedds writes and expects.
- **QoS**: ROS 2's default profile: reliable, volatile, keep-last 10, liveliness
  automatic; writers do not auto-dispose (as rmw_cyclonedds).
- **USER_DATA**: ``typehash=RIHS01_<hex>;`` on every reader and writer, the REP-2011
  type hash Jazzy's rmw puts there (``ros2 topic info -v`` shows it); ``enclave=/;`` on
  the participant.
- **Graph**: the node announces itself on ``ros_discovery_info``
  (``rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_``, reliable, transient-local,
  keep-last 1), listing the GUIDs of its readers and writers, so ``ros2 node list`` and
  ``ros2 topic info -v`` name it.

This is the only module of the project that imports ``cyclonedds``. One participant per
port; ports of one process share the Cyclone domain (created with the port's config and
deleted with the last port, so nothing of Cyclone outlives the ports: no thread, no
socket). Each port takes and delivers on one thread that waits on a DDS waitset.
"""

from __future__ import annotations

import dataclasses
import logging
import operator
import threading
from collections.abc import Callable, Sequence
from typing import Any, Final

from cyclonedds.core import (
    DDSException,
    Entity,
    GuardCondition,
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as _types
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from bridge.rosport import ddsconfig, names
from bridge.rosport.errors import MessageError, RosPortError
from bridge.rosport.msgs import FLOAT_TYPES, INT_RANGES, MESSAGE_TYPES, Message, parse_field_type
from bridge.rosport.port import DEFAULT_NODE_NAME, HISTORY_DEPTH, RosPort, Subscription

__all__ = [
    "DISCOVERY_INFO_TOPIC",
    "PARTICIPANT_ENTITIES_INFO_HASH",
    "DdsPort",
    "cdr_decode",
    "cdr_encode",
    "idl_type",
]

logger = logging.getLogger(__name__)

#: The DDS topic (no ``rt`` prefix) on which rmw announces which node owns which endpoint.
DISCOVERY_INFO_TOPIC: Final = "ros_discovery_info"
#: RIHS01 of rmw_dds_common/msg/ParticipantEntitiesInfo (Jazzy).
PARTICIPANT_ENTITIES_INFO_HASH: Final = (
    "RIHS01_e725f4a506958c79f95dd693b965722c57b19cd18e7eff984f49561b93dc985d"
)
#: Participant USER_DATA, as rmw_cyclonedds writes it for the default enclave.
PARTICIPANT_USER_DATA: Final = b"enclave=/;"
#: Longest a reliable write may block on a full writer history before it fails.
WRITE_BLOCK_S: Final = 1.0
#: Samples taken from a reader per call.
_TAKE_BATCH: Final = 64
#: Waitset timeout: the loop re-checks ``_stopping`` at least this often.
_WAIT_S: Final = 1.0
#: Encapsulation identifiers of plain CDR (XCDR1): big and little endian.
_XCDR1_IDS: Final = (b"\x00\x00", b"\x00\x01")
#: rosidl's name for the one member of an empty message.
_EMPTY_MEMBER: Final = "structure_needs_at_least_one_member"

# The binding's type constructors (sequence[T], array[T, N], bounded_str[N]) are not
# typed as generics; reach them through Any.
types: Any = _types

_PRIMITIVES: Final[dict[str, Any]] = {
    "bool": bool,
    "byte": types.byte,
    "char": types.uint8,  # ROS 2 IDL maps char to uint8
    "int8": types.int8,
    "uint8": types.uint8,
    "int16": types.int16,
    "uint16": types.uint16,
    "int32": types.int32,
    "uint32": types.uint32,
    "int64": types.int64,
    "uint64": types.uint64,
    "float32": types.float32,
    "float64": types.float64,
    "string": str,
}
assert set(_PRIMITIVES) == {*INT_RANGES, *FLOAT_TYPES, "bool", "string"}


# ---------------------------------------------------------------------------------------
# Wire types: one IDL struct per message dataclass, built from its ROS_FIELDS.


@dataclasses.dataclass(frozen=True)
class _Codec:
    idl: type[IdlStruct]
    to_idl: Callable[[Any], IdlStruct]
    from_idl: Callable[[Any], Message]


_CODECS: dict[type[Message], _Codec] = {}
_CODECS_LOCK = threading.RLock()


def _make_idl_struct(ros_type: str, fields: Sequence[tuple[str, Any]]) -> type[IdlStruct]:
    """An IDL struct named as rosidl names the DDS type, final extensibility."""
    typename = names.dds_type_name(ros_type)
    cls = make_idl_struct(typename.replace("::", "_"), typename, dict(fields))
    # What the binding's @annotate.final does; "final" is also its default, stated here
    # because the ROS 2 wire format depends on it (no DHEADER, no member ids).
    cls.__idl_annotations__["extensibility"] = "final"
    return cls


def _codec(msg_type: type[Message]) -> _Codec:
    codec = _CODECS.get(msg_type)
    if codec is not None:
        return codec
    with _CODECS_LOCK:
        codec = _CODECS.get(msg_type)
        if codec is None:
            codec = _build_codec(msg_type)
            _CODECS[msg_type] = codec
        return codec


def _build_codec(msg_type: type[Message]) -> _Codec:
    if not msg_type.ROS_FIELDS:
        idl = _make_idl_struct(msg_type.ROS_TYPE, [(_EMPTY_MEMBER, types.uint8)])

        def empty_to_idl(_: Any) -> IdlStruct:
            return idl(0)  # type: ignore[call-arg]

        def empty_from_idl(_: Any) -> Message:
            return msg_type()

        return _Codec(idl, empty_to_idl, empty_from_idl)

    annotations: list[tuple[str, Any]] = []
    to_parts: list[Callable[[Any], Any]] = []
    from_parts: list[Callable[[Any], Any]] = []
    for name, ros_field_type in msg_type.ROS_FIELDS:
        element, size = parse_field_type(ros_field_type)
        if element in _PRIMITIVES:
            element_annotation = _PRIMITIVES[element]
            element_to: Callable[[Any], Any] | None = None
            element_from: Callable[[Any], Any] | None = None
        else:
            nested = _codec(MESSAGE_TYPES[element])
            element_annotation = nested.idl
            element_to, element_from = nested.to_idl, nested.from_idl
        if size is None:
            annotations.append((name, element_annotation))
            to_parts.append(element_to or _identity)
            from_parts.append(element_from or _identity)
            continue
        if size == 0:
            annotations.append((name, types.sequence[element_annotation]))
        else:
            annotations.append((name, types.array[element_annotation, size]))
        to_parts.append(_mapper(element_to, list))
        from_parts.append(_mapper(element_from, tuple))
    idl = _make_idl_struct(msg_type.ROS_TYPE, annotations)
    getters = [operator.attrgetter(name) for name, _ in msg_type.ROS_FIELDS]
    steps_to = list(zip(getters, to_parts, strict=True))
    steps_from = list(zip(getters, from_parts, strict=True))

    def to_idl(msg: Any) -> IdlStruct:
        return idl(*[conv(get(msg)) for get, conv in steps_to])

    def from_idl(obj: Any) -> Message:
        return msg_type(*[conv(get(obj)) for get, conv in steps_from])

    return _Codec(idl, to_idl, from_idl)


def _identity(value: Any) -> Any:
    return value


def _mapper(
    element: Callable[[Any], Any] | None, container: Callable[[Any], Any]
) -> Callable[[Any], Any]:
    if element is None:
        return container

    def convert(values: Any) -> Any:
        return container([element(v) for v in values])

    return convert


def idl_type(msg_type: type[Message]) -> type[IdlStruct]:
    """The Cyclone DDS IDL struct that carries ``msg_type`` on the wire."""
    return _codec(msg_type).idl


def cdr_encode(msg: Message) -> bytes:
    """``msg`` as this backend writes it: the 4-byte CDR_LE encapsulation header
    (``00 01 00 00``) and the plain-CDR (XCDR1) body.

    Cyclone's writer then pads the sample to a multiple of 4 bytes (zeros the reader
    ignores); this function returns the bytes before that padding, the same bytes as
    ``serialize_cdr`` of rosbags' ROS2_JAZZY type store.
    """
    return bytes(_codec(type(msg)).to_idl(msg).serialize(use_version_2=False))


def cdr_decode(msg_type: type[Message], data: bytes) -> Message:
    """Decode a CDR sample (with its 4-byte encapsulation header) as ``msg_type``.

    Trailing bytes (Cyclone pads samples to a multiple of 4) are ignored.

    Raises:
        MessageError: the bytes are not a plain-CDR ``msg_type`` sample.
    """
    codec = _codec(msg_type)
    if bytes(data[:2]) not in _XCDR1_IDS:
        raise MessageError(
            f"cannot decode {msg_type.ROS_TYPE} from CDR: encapsulation "
            f"{bytes(data[:2]).hex() or 'missing'} is not plain CDR (0000 or 0001)"
        )
    try:
        obj = codec.idl.deserialize(bytes(data), has_header=True)
        return codec.from_idl(obj)
    except MessageError:
        raise
    except Exception as exc:
        raise MessageError(f"cannot decode {msg_type.ROS_TYPE} from CDR: {exc}") from exc


# Graph announcement types (rmw_dds_common, Jazzy: Gid is char[16]).
_GID = _make_idl_struct("rmw_dds_common/msg/Gid", [("data", types.array[types.uint8, 16])])
_NODE_ENTITIES_INFO = _make_idl_struct(
    "rmw_dds_common/msg/NodeEntitiesInfo",
    [
        ("node_namespace", types.bounded_str[256]),
        ("node_name", types.bounded_str[256]),
        ("reader_gid_seq", types.sequence[_GID]),
        ("writer_gid_seq", types.sequence[_GID]),
    ],
)
_PARTICIPANT_ENTITIES_INFO = _make_idl_struct(
    "rmw_dds_common/msg/ParticipantEntitiesInfo",
    [("gid", _GID), ("node_entities_info_seq", types.sequence[_NODE_ENTITIES_INFO])],
)


# ---------------------------------------------------------------------------------------
# QoS


def _user_data(type_hash: str) -> Any:
    return Policy.Userdata(f"typehash={type_hash};".encode("ascii"))


def _writer_qos(type_hash: str) -> Qos:
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(seconds=WRITE_BLOCK_S)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(HISTORY_DEPTH),
        Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.WriterDataLifecycle(autodispose=False),
        _user_data(type_hash),
    )


def _reader_qos(type_hash: str) -> Qos:
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(seconds=WRITE_BLOCK_S)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(HISTORY_DEPTH),
        Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        _user_data(type_hash),
    )


def _discovery_qos() -> Qos:
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(seconds=WRITE_BLOCK_S)),
        Policy.Durability.TransientLocal,
        Policy.DurabilityService(
            cleanup_delay=0,
            history=Policy.History.KeepLast(1),
            max_samples=-1,
            max_instances=-1,
            max_samples_per_instance=-1,
        ),
        Policy.History.KeepLast(1),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.WriterDataLifecycle(autodispose=False),
        _user_data(PARTICIPANT_ENTITIES_INFO_HASH),
    )


def _delete(entity: Entity | None) -> None:
    """Delete a DDS entity now.

    The binding deletes an entity when its Python object is collected (``__del__``);
    calling that here makes deletion deterministic, and the later collection is then a
    no-op (the binding forgets the handle first).
    """
    if entity is not None:
        entity.__del__()


# ---------------------------------------------------------------------------------------
# Domains shared by the ports of one process.


class _DomainUse:
    def __init__(self, domain: Domain, config: str | None) -> None:
        self.domain = domain
        self.config = config
        self.users = 0


_DOMAINS: dict[int, _DomainUse] = {}
_DOMAINS_LOCK = threading.Lock()


def _acquire_domain(domain_id: int, config: str | None) -> None:
    with _DOMAINS_LOCK:
        use = _DOMAINS.get(domain_id)
        if use is None:
            try:
                domain = Domain(domain_id, config)
            except DDSException as exc:
                raise RosPortError(
                    f"cannot create DDS domain {domain_id} (invalid config, or the domain "
                    f"exists already outside bridge.rosport): {exc}"
                ) from exc
            use = _DOMAINS[domain_id] = _DomainUse(domain, config)
        elif use.config != config:
            raise RosPortError(
                f"DDS domain {domain_id} is already open in this process with another "
                "config; every port of one process on one domain must use the same config"
            )
        use.users += 1


def _release_domain(domain_id: int) -> None:
    with _DOMAINS_LOCK:
        use = _DOMAINS.get(domain_id)
        if use is None:
            return
        use.users -= 1
        if use.users == 0:
            del _DOMAINS[domain_id]
            _delete(use.domain)


# ---------------------------------------------------------------------------------------
# Endpoints


class _DdsWriter:
    def __init__(self, port: DdsPort, topic: str, msg_type: type[Message]) -> None:
        codec = _codec(msg_type)
        self._port = port
        self._to_idl = codec.to_idl
        self.dds_topic = names.dds_topic_name(topic)
        self._topic: Topic[Any] | None = Topic(port._participant, self.dds_topic, codec.idl)
        try:
            self._writer: DataWriter[Any] | None = DataWriter(
                port._participant, self._topic, _writer_qos(msg_type.ROS_HASH)
            )
        except Exception:
            _delete(self._topic)
            raise
        self.gid = self._writer.guid.bytes

    def write(self, msg: Message) -> None:
        writer = self._writer
        if writer is None:
            raise RosPortError(f"the writer of {self.dds_topic} is closed")
        writer.write(self._to_idl(msg))

    def matched_count(self) -> int:
        writer = self._writer
        if writer is None:
            return 0
        status: Any = writer.get_publication_matched_status()  # type: ignore[no-untyped-call]
        return int(status.current_count)

    def close(self) -> None:
        writer, self._writer = self._writer, None
        topic, self._topic = self._topic, None
        _delete(writer)
        _delete(topic)
        self._port._forget_writer(self)


class _DdsReader:
    def __init__(self, port: DdsPort, sub: Subscription[Message]) -> None:
        codec = _codec(sub.msg_type)
        self._port = port
        self.sub = sub
        self.from_idl = codec.from_idl
        self.dds_topic = names.dds_topic_name(sub.topic)
        self.closed = False
        self.topic: Topic[Any] = Topic(port._participant, self.dds_topic, codec.idl)
        try:
            self.reader: DataReader[Any] = DataReader(
                port._participant, self.topic, _reader_qos(sub.msg_type.ROS_HASH)
            )
            self.condition = ReadCondition(
                self.reader, SampleState.Any | ViewState.Any | InstanceState.Any
            )
        except Exception:
            _delete(self.topic)
            raise
        self.gid = self.reader.guid.bytes
        port._adopt_reader(self)

    def close(self) -> None:
        self._port._drop_reader(self)


# ---------------------------------------------------------------------------------------
# The port


class DdsPort(RosPort):
    """A port on Cyclone DDS with the ROS 2 wire conventions (``open_port("dds", ...)``).

    Args:
        namespace: see :class:`RosPort`.
        node_name: see :class:`RosPort`.
        domain_id: DDS domain; default ``$ROS_DOMAIN_ID``, else 0 (as ROS 2).
        config: Cyclone DDS config (XML, or ``file://`` URI); default
            ``$CYCLONEDDS_URI``, else Cyclone's defaults. Ports of one process on one
            domain must use the same config. See :mod:`bridge.rosport.ddsconfig`.
        announce: publish the node on ``ros_discovery_info`` so ROS 2 tools name it.

    Raises:
        RosPortError: the domain or participant cannot be created (bad config, the
            domain already open here with another config).
        ValueError: invalid ``domain_id`` or ``config``.
    """

    backend = "dds"

    def __init__(
        self,
        *,
        namespace: str = "",
        node_name: str = DEFAULT_NODE_NAME,
        domain_id: int | None = None,
        config: str | None = None,
        announce: bool = True,
    ) -> None:
        super().__init__(namespace=namespace, node_name=node_name)
        self.domain_id = ddsconfig.resolve_domain_id(domain_id)
        self._io_lock = threading.Lock()
        self._readers: list[_DdsReader] = []
        self._writers: list[_DdsWriter] = []
        self._announcer: DataWriter[Any] | None = None
        self._announcer_topic: Topic[Any] | None = None
        _acquire_domain(self.domain_id, ddsconfig.resolve_config(config))
        try:
            self._participant = DomainParticipant(
                self.domain_id, qos=Qos(Policy.Userdata(PARTICIPANT_USER_DATA))
            )
            self.gid: bytes = self._participant.guid.bytes
            self._guard = GuardCondition(self._participant)
            self._waitset = WaitSet(self._participant)
            self._waitset.attach(self._guard)
            if announce:
                self._announcer_topic = Topic(
                    self._participant, DISCOVERY_INFO_TOPIC, _PARTICIPANT_ENTITIES_INFO
                )
                self._announcer = DataWriter(
                    self._participant, self._announcer_topic, _discovery_qos()
                )
                self._announce()
        except Exception as exc:
            self._release()  # gives the domain back, so a failed port leaves nothing
            if isinstance(exc, DDSException):
                raise RosPortError(
                    f"cannot open a DDS participant on domain {self.domain_id}: {exc}"
                ) from exc
            raise
        self._start()

    # -- RosPort hooks ------------------------------------------------------------------

    def _open_writer(self, topic: str, msg_type: type[Message]) -> _DdsWriter:
        writer = _DdsWriter(self, topic, msg_type)
        with self._io_lock:
            self._writers.append(writer)
        self._announce()
        return writer

    def _open_reader(self, sub: Subscription[Message]) -> _DdsReader:
        reader = _DdsReader(self, sub)
        self._announce()
        return reader

    def _run(self) -> None:
        timeout = duration(seconds=_WAIT_S)
        while not self._stopping.is_set():
            self._waitset.wait(timeout)
            if self._stopping.is_set():
                return
            self._guard.set(False)
            with self._io_lock:
                readers = list(self._readers)
            for reader in readers:
                self._drain(reader)

    def _wake(self) -> None:
        guard = getattr(self, "_guard", None)
        if guard is not None:
            guard.set(True)

    def _release(self) -> None:
        with self._io_lock:
            readers, self._readers = self._readers, []
            self._writers = []
        for reader in readers:
            self._delete_reader(reader)
        participant = getattr(self, "_participant", None)
        _delete(self._announcer)
        _delete(self._announcer_topic)
        self._announcer = self._announcer_topic = None
        _delete(getattr(self, "_waitset", None))
        _delete(getattr(self, "_guard", None))
        # Deleting the participant deletes whatever it still contains.
        _delete(participant)
        _release_domain(self.domain_id)

    # -- internals --------------------------------------------------------------------

    def _drain(self, reader: _DdsReader) -> None:
        while True:
            with self._io_lock:
                if reader.closed:
                    return
                try:
                    samples = reader.reader.take(N=_TAKE_BATCH)
                except Exception:
                    logger.exception("%s: taking from %s failed", self, reader.dds_topic)
                    return
            for sample in samples:
                info = getattr(sample, "sample_info", None)
                if info is None or not info.valid_data:
                    continue  # an instance-state notice (a writer went away), not data
                try:
                    msg = reader.from_idl(sample)
                except MessageError:
                    logger.warning(
                        "%s: dropped a sample on %s that does not fit %s",
                        self,
                        reader.dds_topic,
                        reader.sub.msg_type.__name__,
                        exc_info=True,
                    )
                    continue
                self._deliver(reader.sub, msg)
            if len(samples) < _TAKE_BATCH:
                return

    def _adopt_reader(self, reader: _DdsReader) -> None:
        with self._io_lock:
            self._waitset.attach(reader.condition)
            self._readers.append(reader)

    def _drop_reader(self, reader: _DdsReader) -> None:
        with self._io_lock:
            if reader in self._readers:
                self._readers.remove(reader)
        self._delete_reader(reader)
        if not self.closed:
            self._announce()

    def _delete_reader(self, reader: _DdsReader) -> None:
        with self._io_lock:
            if reader.closed:
                return
            reader.closed = True
            try:
                self._waitset.detach(reader.condition)
            except DDSException:
                logger.debug("%s: detaching %s failed", self, reader.dds_topic, exc_info=True)
            _delete(reader.condition)
            _delete(reader.reader)
            _delete(reader.topic)

    def _forget_writer(self, writer: _DdsWriter) -> None:
        with self._io_lock:
            if writer in self._writers:
                self._writers.remove(writer)
        if not self.closed:
            self._announce()

    def _announce(self) -> None:
        """Publish which readers and writers belong to this node (rmw's graph info)."""
        announcer = self._announcer
        if announcer is None:
            return
        with self._io_lock:
            readers = [_GID(list(r.gid)) for r in self._readers if not r.closed]  # type: ignore[call-arg]
            writers = [_GID(list(w.gid)) for w in self._writers]  # type: ignore[call-arg]
        node = _NODE_ENTITIES_INFO(  # type: ignore[call-arg]
            self.namespace, self.node_name, readers, writers
        )
        info = _PARTICIPANT_ENTITIES_INFO(_GID(list(self.gid)), [node])  # type: ignore[call-arg]
        try:
            announcer.write(info)
        except DDSException:
            logger.warning("%s: announcing the node on %s failed", self, DISCOVERY_INFO_TOPIC)

"""ROS 2 message types as plain frozen dataclasses, independent of any backend.

Each class mirrors one ROS 2 Jazzy interface field for field: same names, same order,
same types (``float64[36]`` is a tuple of exactly 36 floats, ``int16[]`` a tuple of ints
in -32768..32767, nested messages are nested dataclasses). Defaults are the ROS ones
(zeros, empty strings and sequences, ``Quaternion.w = 1.0``).

Every class carries three class constants that the backends read:

- ``ROS_TYPE``: the interface name, e.g. ``"std_msgs/msg/Int16MultiArray"``;
- ``ROS_FIELDS``: ``(name, type)`` pairs in ROS ``.msg`` spelling (``"int16[]"``,
  ``"float64[36]"``, ``"std_msgs/msg/Header"``), the single source the DDS backend
  builds its wire types from;
- ``ROS_HASH``: the REP-2011 type hash ``RIHS01_<sha256 hex>`` that ROS 2 Jazzy puts in
  the endpoints' USER_DATA (a test recomputes every one with rosbags).

Construction normalises and checks every field: sequences (annotated ``Sequence``, any
iterable accepted) are stored as tuples, so messages stay immutable and hashable; integers given
for float fields become floats, and a value that cannot go on the ROS wire (an int16 out
of range, a covariance of 35 values, a string with a NUL) raises :class:`MessageError`
naming the field. So every backend refuses the same bad messages, at the same place.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Final

from bridge.rosport.errors import MessageError

__all__ = [
    "MESSAGE_TYPES",
    "Bool",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Empty",
    "Header",
    "Int16MultiArray",
    "KeyValue",
    "Message",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "Odometry",
    "Point",
    "Pose",
    "PoseWithCovariance",
    "Quaternion",
    "String",
    "Time",
    "Twist",
    "TwistWithCovariance",
    "Vector3",
    "message_type",
    "parse_field_type",
]

RosFields = tuple[tuple[str, str], ...]

#: Integer ROS primitive types and their inclusive ranges.
INT_RANGES: Final[Mapping[str, tuple[int, int]]] = {
    "byte": (0, 0xFF),
    "char": (0, 0xFF),
    "uint8": (0, 0xFF),
    "int8": (-0x80, 0x7F),
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFF_FFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
    "uint64": (0, 0xFFFF_FFFF_FFFF_FFFF),
    "int64": (-0x8000_0000_0000_0000, 0x7FFF_FFFF_FFFF_FFFF),
}
FLOAT_TYPES: Final = frozenset({"float32", "float64"})
PRIMITIVE_TYPES: Final = frozenset({*INT_RANGES, *FLOAT_TYPES, "bool", "string"})


def parse_field_type(ros_type: str) -> tuple[str, int | None]:
    """Split a ROS field type into its element type and its shape.

    Returns ``(element, size)``: ``size`` is ``None`` for a single value, ``0`` for an
    unbounded sequence (``int16[]``) and ``N`` for a fixed array (``float64[36]``).
    Bounded sequences (``int16[<=5]``) are not used by our messages and are refused.

    Raises:
        ValueError: the spelling is not one of those three forms.
    """
    element, bracket, rest = ros_type.partition("[")
    if not bracket:
        return element, None
    if rest == "]":
        return element, 0
    if rest.endswith("]") and rest[:-1].isdigit() and int(rest[:-1]) > 0:
        return element, int(rest[:-1])
    raise ValueError(f"unsupported ROS field type {ros_type!r}")


class Message:
    """Base of every message dataclass: the ROS constants and the field checks."""

    __slots__ = ()

    ROS_TYPE: ClassVar[str]
    ROS_FIELDS: ClassVar[RosFields]
    ROS_HASH: ClassVar[str]

    def __post_init__(self) -> None:
        for name, check in _checks(type(self)):
            value = getattr(self, name)
            checked = check(value, name)
            if checked is not value:
                # Frozen dataclass: normalisation happens once, here, at construction.
                object.__setattr__(self, name, checked)


# ---------------------------------------------------------------------------------------
# builtin_interfaces, std_msgs


@dataclass(frozen=True, slots=True)
class Time(Message):
    """builtin_interfaces/msg/Time: seconds and nanoseconds since the epoch (or a clock's 0)."""

    ROS_TYPE: ClassVar[str] = "builtin_interfaces/msg/Time"
    ROS_FIELDS: ClassVar[RosFields] = (("sec", "int32"), ("nanosec", "uint32"))
    ROS_HASH: ClassVar[str] = (
        "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"
    )

    sec: int = 0
    nanosec: int = 0

    @classmethod
    def from_ns(cls, ns: int) -> Time:
        """The time ``ns`` nanoseconds after zero (``nanosec`` always in 0..999999999)."""
        sec, nanosec = divmod(ns, 1_000_000_000)
        return cls(sec, nanosec)

    def to_ns(self) -> int:
        """This time in nanoseconds."""
        return self.sec * 1_000_000_000 + self.nanosec


@dataclass(frozen=True, slots=True)
class Header(Message):
    """std_msgs/msg/Header: a stamp and the coordinate frame the data is in."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/Header"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("stamp", "builtin_interfaces/msg/Time"),
        ("frame_id", "string"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"
    )

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass(frozen=True, slots=True)
class String(Message):
    """std_msgs/msg/String."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/String"
    ROS_FIELDS: ClassVar[RosFields] = (("data", "string"),)
    ROS_HASH: ClassVar[str] = (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )

    data: str = ""


@dataclass(frozen=True, slots=True)
class Bool(Message):
    """std_msgs/msg/Bool."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/Bool"
    ROS_FIELDS: ClassVar[RosFields] = (("data", "bool"),)
    ROS_HASH: ClassVar[str] = (
        "RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9"
    )

    data: bool = False


@dataclass(frozen=True, slots=True)
class Empty(Message):
    """std_msgs/msg/Empty. On the wire it carries the one ``uint8`` that ROS 2's IDL adds
    to every empty structure (``structure_needs_at_least_one_member``), always 0."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/Empty"
    ROS_FIELDS: ClassVar[RosFields] = ()
    ROS_HASH: ClassVar[str] = (
        "RIHS01_20b625256f32d5dbc0d04fee44f43c41e51c70d3502f84b4a08e7a9c26a96312"
    )


@dataclass(frozen=True, slots=True)
class MultiArrayDimension(Message):
    """std_msgs/msg/MultiArrayDimension."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/MultiArrayDimension"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("label", "string"),
        ("size", "uint32"),
        ("stride", "uint32"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_5e773a60a4c7fc8a54985f307c7837aa2994252a126c301957a24e31282c9cbe"
    )

    label: str = ""
    size: int = 0
    stride: int = 0


@dataclass(frozen=True, slots=True)
class MultiArrayLayout(Message):
    """std_msgs/msg/MultiArrayLayout."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/MultiArrayLayout"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("dim", "std_msgs/msg/MultiArrayDimension[]"),
        ("data_offset", "uint32"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_4c66e6f78e740ac103a94cf63259f968e48c617e7699e829b63c21a5cb50dac6"
    )

    dim: Sequence[MultiArrayDimension] = ()
    data_offset: int = 0


@dataclass(frozen=True, slots=True)
class Int16MultiArray(Message):
    """std_msgs/msg/Int16MultiArray (``/wheel_instructions``: ``[command, speed, distance]``)."""

    ROS_TYPE: ClassVar[str] = "std_msgs/msg/Int16MultiArray"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("layout", "std_msgs/msg/MultiArrayLayout"),
        ("data", "int16[]"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_b58810e8e5b90fb19a5062469eb8409f5ab11a446d60de7157a1457e52a076ce"
    )

    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: Sequence[int] = ()


# ---------------------------------------------------------------------------------------
# geometry_msgs, nav_msgs


@dataclass(frozen=True, slots=True)
class Point(Message):
    """geometry_msgs/msg/Point, metres."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/Point"
    ROS_FIELDS: ClassVar[RosFields] = (("x", "float64"), ("y", "float64"), ("z", "float64"))
    ROS_HASH: ClassVar[str] = (
        "RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881"
    )

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Quaternion(Message):
    """geometry_msgs/msg/Quaternion; the ROS default is the identity rotation (w = 1)."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/Quaternion"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("x", "float64"),
        ("y", "float64"),
        ("z", "float64"),
        ("w", "float64"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684"
    )

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0

    @classmethod
    def from_yaw(cls, yaw_rad: float) -> Quaternion:
        """The rotation by ``yaw_rad`` about +z (counter-clockwise seen from above)."""
        half = 0.5 * yaw_rad
        return cls(0.0, 0.0, math.sin(half), math.cos(half))

    def yaw_rad(self) -> float:
        """The rotation about +z, in -pi..pi (exact for planar rotations)."""
        return math.atan2(
            2.0 * (self.w * self.z + self.x * self.y),
            1.0 - 2.0 * (self.y * self.y + self.z * self.z),
        )


@dataclass(frozen=True, slots=True)
class Pose(Message):
    """geometry_msgs/msg/Pose."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/Pose"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("position", "geometry_msgs/msg/Point"),
        ("orientation", "geometry_msgs/msg/Quaternion"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa"
    )

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


_ZERO_COVARIANCE: Final = (0.0,) * 36


@dataclass(frozen=True, slots=True)
class PoseWithCovariance(Message):
    """geometry_msgs/msg/PoseWithCovariance: 6x6 row-major covariance of (x, y, z, rot x,
    rot y, rot z)."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/PoseWithCovariance"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("pose", "geometry_msgs/msg/Pose"),
        ("covariance", "float64[36]"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb"
    )

    pose: Pose = field(default_factory=Pose)
    covariance: Sequence[float] = _ZERO_COVARIANCE


@dataclass(frozen=True, slots=True)
class Vector3(Message):
    """geometry_msgs/msg/Vector3."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/Vector3"
    ROS_FIELDS: ClassVar[RosFields] = (("x", "float64"), ("y", "float64"), ("z", "float64"))
    ROS_HASH: ClassVar[str] = (
        "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d"
    )

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Twist(Message):
    """geometry_msgs/msg/Twist: linear (m/s) and angular (rad/s) velocity."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/Twist"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("linear", "geometry_msgs/msg/Vector3"),
        ("angular", "geometry_msgs/msg/Vector3"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
    )

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class TwistWithCovariance(Message):
    """geometry_msgs/msg/TwistWithCovariance: 6x6 row-major covariance."""

    ROS_TYPE: ClassVar[str] = "geometry_msgs/msg/TwistWithCovariance"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("twist", "geometry_msgs/msg/Twist"),
        ("covariance", "float64[36]"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_49f574f033f095d8b6cd1beaca5ca7925e296e84af1716d16c89d38b059c8c18"
    )

    twist: Twist = field(default_factory=Twist)
    covariance: Sequence[float] = _ZERO_COVARIANCE


@dataclass(frozen=True, slots=True)
class Odometry(Message):
    """nav_msgs/msg/Odometry: pose in ``header.frame_id``, twist in ``child_frame_id``."""

    ROS_TYPE: ClassVar[str] = "nav_msgs/msg/Odometry"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("header", "std_msgs/msg/Header"),
        ("child_frame_id", "string"),
        ("pose", "geometry_msgs/msg/PoseWithCovariance"),
        ("twist", "geometry_msgs/msg/TwistWithCovariance"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
    )

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


# ---------------------------------------------------------------------------------------
# diagnostic_msgs


@dataclass(frozen=True, slots=True)
class KeyValue(Message):
    """diagnostic_msgs/msg/KeyValue."""

    ROS_TYPE: ClassVar[str] = "diagnostic_msgs/msg/KeyValue"
    ROS_FIELDS: ClassVar[RosFields] = (("key", "string"), ("value", "string"))
    ROS_HASH: ClassVar[str] = (
        "RIHS01_d68081eaa540288c5440753baecef0c4e16e81a5f78ad68902ded5100413bb42"
    )

    key: str = ""
    value: str = ""


@dataclass(frozen=True, slots=True)
class DiagnosticStatus(Message):
    """diagnostic_msgs/msg/DiagnosticStatus.

    ``level`` is the ROS ``byte`` field, held here as an int 0..255; the level constants
    are the ROS ones (``byte OK=0``, ``WARN=1``, ``ERROR=2``, ``STALE=3``). rclpy spells a
    ``byte`` as a one-byte ``bytes`` object; the rclpy backend converts both ways.
    """

    OK: ClassVar[int] = 0
    WARN: ClassVar[int] = 1
    ERROR: ClassVar[int] = 2
    STALE: ClassVar[int] = 3

    ROS_TYPE: ClassVar[str] = "diagnostic_msgs/msg/DiagnosticStatus"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("level", "byte"),
        ("name", "string"),
        ("message", "string"),
        ("hardware_id", "string"),
        ("values", "diagnostic_msgs/msg/KeyValue[]"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4"
    )

    level: int = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: Sequence[KeyValue] = ()


@dataclass(frozen=True, slots=True)
class DiagnosticArray(Message):
    """diagnostic_msgs/msg/DiagnosticArray (``/diagnostics``)."""

    ROS_TYPE: ClassVar[str] = "diagnostic_msgs/msg/DiagnosticArray"
    ROS_FIELDS: ClassVar[RosFields] = (
        ("header", "std_msgs/msg/Header"),
        ("status", "diagnostic_msgs/msg/DiagnosticStatus[]"),
    )
    ROS_HASH: ClassVar[str] = (
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
    )

    header: Header = field(default_factory=Header)
    status: Sequence[DiagnosticStatus] = ()


#: Every message type, by ROS interface name.
MESSAGE_TYPES: Final[Mapping[str, type[Message]]] = {
    cls.ROS_TYPE: cls
    for cls in (
        Time,
        Header,
        String,
        Bool,
        Empty,
        MultiArrayDimension,
        MultiArrayLayout,
        Int16MultiArray,
        Point,
        Quaternion,
        Pose,
        PoseWithCovariance,
        Vector3,
        Twist,
        TwistWithCovariance,
        Odometry,
        KeyValue,
        DiagnosticStatus,
        DiagnosticArray,
    )
}


def message_type(ros_type: str) -> type[Message]:
    """The dataclass for a ROS interface name such as ``"std_msgs/msg/String"``.

    Raises:
        KeyError: no message type of that name is defined here.
    """
    try:
        return MESSAGE_TYPES[ros_type]
    except KeyError:
        raise KeyError(f"no message type {ros_type!r}; known: {sorted(MESSAGE_TYPES)}") from None


# ---------------------------------------------------------------------------------------
# Field checks, compiled once per class from ROS_FIELDS.

_Check = Callable[[Any, str], Any]
_CHECKS: dict[type[Message], tuple[tuple[str, _Check], ...]] = {}


def _checks(cls: type[Message]) -> tuple[tuple[str, _Check], ...]:
    checks = _CHECKS.get(cls)
    if checks is None:
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        spec_names = [name for name, _ in cls.ROS_FIELDS]
        if names != spec_names:
            raise TypeError(f"{cls.__name__}: dataclass fields {names} != ROS_FIELDS {spec_names}")
        checks = tuple((name, _field_check(cls, typ)) for name, typ in cls.ROS_FIELDS)
        _CHECKS[cls] = checks
    return checks


def _fail(cls: type[Message], name: str, text: str) -> MessageError:
    return MessageError(f"{cls.__name__}.{name}: {text}")


def _field_check(cls: type[Message], ros_type: str) -> _Check:
    element, size = parse_field_type(ros_type)
    one = _element_check(cls, element)
    if size is None:
        return one
    fast_type = float if element in FLOAT_TYPES else None

    def check_many(value: Any, name: str) -> tuple[Any, ...]:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise _fail(cls, name, f"expected a sequence of {element}, got {type(value).__name__}")
        if (
            fast_type is not None
            and type(value) is tuple
            and all(type(v) is fast_type for v in value)
        ):
            items: tuple[Any, ...] = value
        else:
            items = tuple(one(v, f"{name}[{i}]") for i, v in enumerate(value))
        if size and len(items) != size:
            raise _fail(cls, name, f"expected exactly {size} values, got {len(items)}")
        return items

    return check_many


def _element_check(cls: type[Message], element: str) -> _Check:
    if element in INT_RANGES:
        low, high = INT_RANGES[element]

        def check_int(value: Any, name: str) -> int:
            if type(value) is not int:
                if isinstance(value, bool):
                    raise _fail(cls, name, f"expected {element}, got a bool")
                try:
                    value = operator.index(value)
                except TypeError:
                    raise _fail(
                        cls, name, f"expected {element}, got {type(value).__name__}"
                    ) from None
            if not low <= value <= high:
                raise _fail(cls, name, f"{value} is out of range for {element} ({low}..{high})")
            return int(value)

        return check_int
    if element in FLOAT_TYPES:

        def check_float(value: Any, name: str) -> float:
            if type(value) is float:
                return value
            if not isinstance(value, (bool, str, bytes, bytearray)):
                try:
                    return float(value)
                except (TypeError, ValueError):
                    pass
            raise _fail(cls, name, f"expected {element}, got {type(value).__name__}")

        return check_float
    if element == "bool":

        def check_bool(value: Any, name: str) -> bool:
            if not isinstance(value, bool):
                raise _fail(cls, name, f"expected bool, got {type(value).__name__}")
            return value

        return check_bool
    if element == "string":

        def check_string(value: Any, name: str) -> str:
            if not isinstance(value, str):
                raise _fail(cls, name, f"expected str, got {type(value).__name__}")
            if "\x00" in value:
                raise _fail(cls, name, "a ROS string cannot contain NUL")
            return value

        return check_string
    nested = MESSAGE_TYPES.get(element)
    if nested is None:
        raise TypeError(f"{cls.__name__}: unknown field type {element!r}")

    def check_nested(value: Any, name: str) -> Message:
        if not isinstance(value, nested):
            raise _fail(cls, name, f"expected {nested.__name__}, got {type(value).__name__}")
        return value

    return check_nested

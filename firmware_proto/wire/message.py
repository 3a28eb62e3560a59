"""The base class of every protocol message.

Concrete classes are generated into :mod:`firmware_proto.wire.messages` from
``protocol.toml``: immutable named tuples of raw integers (units in the field names,
e.g. ``yaw_rate_mrad_s``); enum-typed fields hold plain ``int`` values that compare equal
to the generated ``IntEnum`` members. Tuples, not frozen dataclasses, because the
decoder builds one per received frame straight from ``struct.unpack`` (the hot path).
Unlike plain named tuples, messages compare equal only to messages of the same type.

Framing lives in :mod:`firmware_proto.wire.framing` (serial) and
:mod:`firmware_proto.wire.canmap` (CAN).
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any, ClassVar, TypeVar

from firmware_proto.errors import EncodeError

__all__ = ["Message", "field_error"]

M = TypeVar("M", bound="Message")


class Message:
    """A protocol message. Subclasses are generated; do not subclass by hand.

    Each generated class derives from ``Message`` first and a ``NamedTuple`` of its fields
    second, so that the equality and hashing below take precedence over the tuple's.

    Class attributes:
        MSG_ID: message id (serial frame id; CAN identifier ``MSG_ID << 4 | node``).
        NAME: upper-case protocol name, e.g. ``"MOTION"``.
        LENGTH: payload length in bytes (fixed per type, at most 8).
        DIRECTION: ``"host_to_controller"`` or ``"controller_to_host"``.
        PRIORITY: priority class name (``"emergency"`` ... ``"config"``).
        FIELDS: public field names in wire order.
        ENUMS: field name -> enum class, for fields that hold enum codes.
    """

    __slots__ = ()

    MSG_ID: ClassVar[int]
    NAME: ClassVar[str]
    LENGTH: ClassVar[int]
    DIRECTION: ClassVar[str]
    PRIORITY: ClassVar[str]
    FIELDS: ClassVar[tuple[str, ...]]
    ENUMS: ClassVar[dict[str, type[IntEnum]]]

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; with ``strict`` also the semantic limits (e.g. MOTION speed
        0..60), else only the wire range (so a test host can send a value the controller must
        refuse). EncodeError, naming the field, for a value not an int or out of range."""
        raise NotImplementedError

    @classmethod
    def unpack(cls: type[M], payload: bytes) -> M:
        """Strict decode of one payload; DecodeError for a wrong length or a value out of range."""
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        # super() is the generated NamedTuple base: tuple equality, once types match.
        return type(self) is type(other) and super().__eq__(other)

    def __ne__(self, other: object) -> bool:
        return not self.__eq__(other)

    def __hash__(self) -> int:
        return hash((self.MSG_ID, *self))  # type: ignore[misc]

    def to_dict(self) -> dict[str, int]:
        """Field values by name, in wire order."""
        return {name: getattr(self, name) for name in self.FIELDS}

    def describe(self) -> str:
        """One human-readable line, enum codes shown by name: ``MOTION seq=1 command=FWD``."""
        parts = [self.NAME]
        for name in self.FIELDS:
            value = getattr(self, name)
            enum = self.ENUMS.get(name)
            if enum is not None and value in enum._value2member_map_:
                value = enum(value).name
            parts.append(f"{name}={value}")
        return " ".join(parts)


def field_error(
    message: str, field: str, value: Any, lo: int, hi: int, *, limit: bool = False
) -> EncodeError:
    """Build the :class:`EncodeError` for a bad field value (used by generated code)."""
    if not isinstance(value, int):
        text = f"{message}.{field} must be an int, got {type(value).__name__} {value!r}"
    else:
        kind = "limit" if limit else "range"
        text = f"{message}.{field}={value} outside its {kind} {lo}..{hi}"
    return EncodeError(text, message=message, field=field)

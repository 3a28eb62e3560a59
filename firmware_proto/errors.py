"""Exceptions raised by :mod:`firmware_proto`; all but ``ProtoError`` and ``SpecError``
are also ValueError::

    ProtoError
     +-- SpecError          the declarative message spec is malformed (build time)
     +-- EncodeError        a field value cannot be encoded (names the field)
     +-- DecodeError        a payload or frame cannot be decoded (strict APIs only)
     +-- DescriptionError   the rover description file is missing or invalid
     +-- PlanError          a command plan fails its JSON schema
     +-- MapError           a map is unknown, unreadable, not JSON or invalid (``violations``)
     +-- VerdictError       a document is not the gate's verdict JSON
     +-- UplinkError        a plan uplink or cancel is refused; ``reason`` is the rover's code
     +-- BindPolicyError    an HTTP server may not listen there without a (valid) token
     +-- ValueArgumentError a command-line value breaks its rule; also ArgumentTypeError

Stream decoders never raise on bad input: they count it (``framing.FrameDecoder``).
"""

from __future__ import annotations

__all__ = [
    "BindPolicyError",
    "DecodeError",
    "DescriptionError",
    "EncodeError",
    "MapError",
    "PlanError",
    "ProtoError",
    "SpecError",
    "UplinkError",
    "VerdictError",
]


class ProtoError(Exception):
    """Root of every exception raised by firmware_proto."""


class SpecError(ProtoError):
    """The declarative protocol spec is malformed."""


class EncodeError(ProtoError, ValueError):
    """A message cannot be encoded; the message names the offending field.

    Attributes:
        message: name of the message type.
        field: name of the field, or ``""`` when the problem is not one field.
    """

    def __init__(self, text: str, *, message: str = "", field: str = "") -> None:
        super().__init__(text)
        self.message = message
        self.field = field


class DecodeError(ProtoError, ValueError):
    """A payload or frame cannot be decoded (raised by strict, non-streaming APIs)."""


class DescriptionError(ProtoError, ValueError):
    """The rover description is missing, malformed or out of range."""


class PlanError(ProtoError, ValueError):
    """A command plan fails the plan schema; ``violations``: ``(json_pointer, message)``
    pairs, one per schema violation."""

    def __init__(self, violations: list[tuple[str, str]]) -> None:
        self.violations = violations
        text = "; ".join(f"{ptr or '/'}: {msg}" for ptr, msg in violations)
        super().__init__(f"plan fails schema: {text}")


class MapError(ProtoError, ValueError):
    """A map cannot be used.

    Attributes:
        source: the file (or map name) that was read.
        violations: ``(json_pointer, message)`` pairs, sorted by pointer; the pointer is
            ``""`` for a problem with the whole document (unreadable, not JSON).
    """

    def __init__(self, source: str, violations: list[tuple[str, str]]) -> None:
        self.source = source
        self.violations = list(violations)
        lines = "; ".join(f"{ptr or '/'}: {msg}" for ptr, msg in self.violations)
        super().__init__(f"{source}: invalid map: {lines}")


class VerdictError(ProtoError, ValueError):
    """A document is not the gate's verdict JSON (:mod:`firmware_proto.model.verdict`);
    ``pointers``: where it departs from the shape."""

    def __init__(self, message: str, pointers: tuple[str, ...] = ()) -> None:
        self.pointers = pointers
        super().__init__(message)


class UplinkError(ProtoError, ValueError):
    """A plan uplink (or a cancel) is refused by :mod:`firmware_proto.model.uplink`.

    Attributes:
        reason: the short code the rover answers with, one of
            :data:`firmware_proto.model.uplink.REFUSALS`.
        detail: one sentence saying what exactly is wrong (names the field).
    """

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}")


class BindPolicyError(ProtoError, ValueError):
    """An HTTP server of ours may not listen on that address without a token, or its
    token is malformed (:mod:`firmware_proto.http.bindpolicy`)."""

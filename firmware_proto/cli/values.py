"""One check per kind of value that command lines take, shared by every ``rover`` command.

Each function is an ``argparse`` type: it takes the option's text and returns the value,
or raises :class:`ValueArgumentError` (a usage error, exit status 2) with the same words
whichever command refused it, e.g. ``baud must be an integer in 50..4000000 (bit/s), got
'0'``. :func:`check` applies one to a value from elsewhere (a launch file's parameter, a
stack's configuration). Each function's docstring and the ``*_RANGE`` constants state
its limits.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import TypeVar

from firmware_proto.errors import ProtoError

__all__ = [
    "BAUD_RANGE",
    "DOMAIN_RANGE",
    "NODE_RANGE",
    "ValueArgumentError",
    "baud",
    "can_node",
    "can_node_or_broadcast",
    "check",
    "domain_id",
    "host_port",
    "loss_ratio",
    "non_negative",
    "non_negative_int",
    "positive",
    "positive_int",
    "rt_priority",
    "tcp_port",
    "yielding_nice",
]

BAUD_RANGE = (50, 4_000_000)
"""Serial baud rates accepted, bit/s."""
NODE_RANGE = (1, 15)
"""CAN node ids of a controller."""
DOMAIN_RANGE = (0, 232)
"""ROS 2 domain ids that map to valid DDS ports on Linux."""

T = TypeVar("T")


class ValueArgumentError(ProtoError, ValueError, argparse.ArgumentTypeError):
    """A value on a command line is out of its range or not a number; says which rule
    it broke. An ``argparse.ArgumentTypeError`` (a usage error) and a ``ValueError``."""


def _integer(text: str, what: str, low: int, high: int, unit: str = "") -> int:
    try:
        value = int(str(text).strip(), 0)
    except ValueError:
        value = None
    if value is None or not low <= value <= high:
        tail = f" ({unit})" if unit else ""
        raise ValueArgumentError(f"{what} must be an integer in {low}..{high}{tail}, got {text!r}")
    return value


def baud(text: str) -> int:
    """A serial baud rate, bit/s, in :data:`BAUD_RANGE`."""
    return _integer(text, "baud", *BAUD_RANGE, unit="bit/s")


def can_node(text: str) -> int:
    """A controller's CAN node id, in :data:`NODE_RANGE`."""
    return _integer(text, "node", *NODE_RANGE)


def can_node_or_broadcast(text: str) -> int:
    """A CAN node id, or 0 for broadcast (``rover frame encode --can``)."""
    return _integer(text, "node", 0, NODE_RANGE[1], unit="0: broadcast")


def tcp_port(text: str) -> int:
    """A TCP port to listen on: 1..65535, or 0 for one the system picks."""
    return _integer(text, "port", 0, 65535, unit="0 picks a free one")


def domain_id(text: str) -> int:
    """A ROS 2 domain id, in :data:`DOMAIN_RANGE`."""
    return _integer(text, "ROS domain id", *DOMAIN_RANGE)


def rt_priority(text: str) -> int:
    """A real-time priority, 1..99, or 0 for normal scheduling (docs/realtime.md)."""
    return _integer(text, "real-time priority", 0, 99, unit="0: normal scheduling")


def yielding_nice(text: str) -> int:
    """A nice value a program may set without privilege: 0..19."""
    return _integer(text, "nice", 0, 19)


def host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` of a service to connect to (port 1..65535) -> ``(host, port)``."""
    host, colon, port = str(text).rpartition(":")
    if not colon or not host:
        raise ValueArgumentError(f"expected HOST:PORT, got {text!r}")
    return host, _integer(port, "port", 1, 65535)


def _number(text: str, what: str, *, strict: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0 or (strict and value == 0):
        bound = "> 0" if strict else ">= 0"
        raise ValueArgumentError(f"{what} must be a finite number {bound}, got {text!r}")
    return value


def positive(text: str) -> float:
    """A finite number > 0 (a duration, a rate, a factor)."""
    return _number(text, "value", strict=True)


def non_negative(text: str) -> float:
    """A finite number >= 0 (a duration where 0 means none)."""
    return _number(text, "value", strict=False)


def loss_ratio(text: str) -> float:
    """A share of messages lost, a number in [0, 1) (1 would lose everything)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value < 1.0:
        raise ValueArgumentError(f"loss must be a number in [0, 1), got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, "value", 1, 2**31 - 1)


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _integer(text, "value", 0, 2**31 - 1)


def check(kind: Callable[[str], T], value: object, name: str) -> T:
    """Apply one of these checks to a value from elsewhere (a parameter, a file);
    the error names ``name``.

    Raises:
        ValueArgumentError: the value breaks the rule.
    """
    try:
        return kind(str(value))
    except ValueArgumentError as exc:
        raise ValueArgumentError(f"{name}: {exc}") from None

"""Seeded, non-trivial messages of every type, and conversion to and from rosbags.

Shared by the tests and by the peer process (tests/bridge/peer.py), which must build the
very same messages from the same seeds.
"""

from __future__ import annotations

import math
import random
from typing import Any

from bridge.rosport.msgs import (
    FLOAT_TYPES,
    INT_RANGES,
    MESSAGE_TYPES,
    Message,
    parse_field_type,
)

# Strings that exercise the CDR string encoding: empty, ASCII, multi-byte UTF-8,
# lengths that land on each 4-byte alignment.
_STRINGS = ("", "a", "ab", "abc", "odom", "base_link", "rover1/odom", "Ünïcødé ☾", "fault:crc")


def random_value(ros_type: str, rng: random.Random) -> Any:
    """A random valid value for one ROS field type, edge values included."""
    element, size = parse_field_type(ros_type)
    if size is not None:
        count = size or rng.randint(0, 4)
        return tuple(random_value(element, rng) for _ in range(count))
    if element in INT_RANGES:
        low, high = INT_RANGES[element]
        return rng.choice((low, high, 0, 1, rng.randint(low, high)))
    if element in FLOAT_TYPES:
        value = rng.choice((0.0, -1.5, math.pi, 1e-300, -1e300, math.inf, rng.uniform(-1e6, 1e6)))
        if element == "float32":
            value = float(rng.randint(-1000, 1000)) / 8.0
        return value
    if element == "bool":
        return rng.random() < 0.5
    if element == "string":
        return rng.choice(_STRINGS) + "".join(
            rng.choice("xyz_/.") for _ in range(rng.randint(0, 5))
        )
    return random_message(MESSAGE_TYPES[element], rng)


def random_message(msg_type: type[Message], rng: random.Random) -> Message:
    """A message of ``msg_type`` with every field set from ``rng``."""
    return msg_type(*[random_value(t, rng) for _, t in msg_type.ROS_FIELDS])


def sample(msg_type: type[Message], seed: int) -> Message:
    """The message of ``msg_type`` for ``seed`` (the same in every process)."""
    return random_message(msg_type, random.Random(f"{msg_type.ROS_TYPE}:{seed}"))


def topic_for(msg_type: type[Message]) -> str:
    """A topic name per type, e.g. ``Int16MultiArray`` -> ``int16_multi_array``."""
    name = msg_type.__name__
    return "".join(
        ("_" + c.lower()) if c.isupper() and i else c.lower() for i, c in enumerate(name)
    )


# -- rosbags (the peer implementation we did not write) ---------------------------------

# rosbags holds a ROS ``byte`` as a signed int8 (same octet on the wire); our dataclasses
# hold it as 0..255, like rclpy's one-byte ``bytes``.
_NUMPY_DTYPES = {
    "bool": "bool",
    "byte": "int8",
    "char": "uint8",
    "uint8": "uint8",
    "int8": "int8",
    "uint16": "uint16",
    "int16": "int16",
    "uint32": "uint32",
    "int32": "int32",
    "uint64": "uint64",
    "int64": "int64",
    "float32": "float32",
    "float64": "float64",
}


def to_rosbags(msg: Message, typestore: Any) -> Any:
    """The same message as an instance of rosbags' class for its type."""
    import numpy as np

    cls = typestore.types[msg.ROS_TYPE]
    if not msg.ROS_FIELDS:
        return cls(structure_needs_at_least_one_member=0)
    values: dict[str, Any] = {}
    for name, ros_type in msg.ROS_FIELDS:
        element, size = parse_field_type(ros_type)
        value = getattr(msg, name)
        if element in MESSAGE_TYPES:
            if size is None:
                values[name] = to_rosbags(value, typestore)
            else:
                values[name] = [to_rosbags(v, typestore) for v in value]
        elif size is not None and element != "string":
            if element == "byte":
                value = [v - 256 if v > 127 else v for v in value]
            values[name] = np.array(value, dtype=_NUMPY_DTYPES[element])
        elif size is not None:
            values[name] = list(value)
        elif element == "byte":
            values[name] = value - 256 if value > 127 else value
        else:
            values[name] = value
    return cls(**values)


def from_rosbags(obj: Any, msg_type: type[Message]) -> Message:
    """Our dataclass for a rosbags message object."""
    values: list[Any] = []
    for name, ros_type in msg_type.ROS_FIELDS:
        element, size = parse_field_type(ros_type)
        value = getattr(obj, name)
        if element in MESSAGE_TYPES:
            nested = MESSAGE_TYPES[element]
            if size is None:
                values.append(from_rosbags(value, nested))
            else:
                values.append(tuple(from_rosbags(v, nested) for v in value))
        elif size is not None:
            items = [v.item() if hasattr(v, "item") else v for v in value]
            values.append(tuple(v & 0xFF for v in items) if element == "byte" else tuple(items))
        elif element == "byte":
            values.append(int(value) & 0xFF)
        else:
            values.append(value.item() if hasattr(value, "item") else value)
    return msg_type(*values)

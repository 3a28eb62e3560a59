"""Seeded, non-trivial ROS 2 messages of every type the product uses.

:func:`sample` builds the same message for the same type and seed in every process, from
the generated class's own field description (``SLOT_TYPES``), edge values included.
"""

from __future__ import annotations

import importlib
import math
import random
from typing import Any

from rosidl_parser import definition

# Strings that exercise the CDR string encoding: empty, ASCII, multi-byte UTF-8,
# lengths that land on each 4-byte alignment.
_STRINGS = ("", "a", "ab", "abc", "odom", "base_link", "rover1/odom", "Ünïcødé ☾", "fault:crc")

_INT_RANGES = {
    "int8": (-0x80, 0x7F),
    "uint8": (0, 0xFF),
    "int16": (-0x8000, 0x7FFF),
    "uint16": (0, 0xFFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
    "uint32": (0, 0xFFFF_FFFF),
    "int64": (-0x8000_0000_0000_0000, 0x7FFF_FFFF_FFFF_FFFF),
    "uint64": (0, 0xFFFF_FFFF_FFFF_FFFF),
}


def _value(slot: Any, rng: random.Random) -> Any:
    if isinstance(slot, definition.Array):
        return [_value(slot.value_type, rng) for _ in range(slot.size)]
    if isinstance(slot, definition.AbstractSequence):
        return [_value(slot.value_type, rng) for _ in range(rng.randint(0, 4))]
    if isinstance(slot, definition.AbstractString):
        return rng.choice(_STRINGS) + "".join(
            rng.choice("xyz_/.") for _ in range(rng.randint(0, 5))
        )
    if isinstance(slot, definition.NamespacedType):
        module = importlib.import_module(".".join(slot.namespaces))
        return random_message(getattr(module, slot.name), rng)
    name = slot.typename
    if name in _INT_RANGES:
        low, high = _INT_RANGES[name]
        return rng.choice((low, high, 0, 1, rng.randint(low, high)))
    if name == "double":
        return rng.choice((0.0, -1.5, math.pi, 1e-300, -1e300, math.inf, rng.uniform(-1e6, 1e6)))
    if name == "float":
        return float(rng.randint(-1000, 1000)) / 8.0
    if name == "boolean":
        return rng.random() < 0.5
    if name == "octet":
        return bytes((rng.randint(0, 255),))
    raise TypeError(f"no sample for ROS type {name}")


def random_message(msg_type: type[Any], rng: random.Random) -> Any:
    """A message of ``msg_type`` with every field set from ``rng``."""
    names = msg_type.get_fields_and_field_types()
    slots = zip(names, msg_type.SLOT_TYPES, strict=True)
    return msg_type(**{n: _value(s, rng) for n, s in slots})


def sample(msg_type: type[Any], seed: int) -> Any:
    """The message of ``msg_type`` for ``seed`` (the same in every process)."""
    return random_message(
        msg_type, random.Random(f"{msg_type.__module__}.{msg_type.__name__}:{seed}")
    )


def topic_for(msg_type: type[Any]) -> str:
    """A topic name per type, e.g. ``Int16MultiArray`` -> ``int16_multi_array``."""
    name = msg_type.__name__
    return "".join(
        ("_" + c.lower()) if c.isupper() and i else c.lower() for i, c in enumerate(name)
    )

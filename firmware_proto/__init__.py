"""The base of the stack, which every other part may import, and which imports none of
them (docs/architecture.md, Parts and layers). Six folders, by what they hold:

- ``wire/`` (pure): the wire protocol generated from ``wire/protocol.toml``
  (docs/protocol.md), its code generators, test vectors, the C codec and firmware core;
- ``model/`` (pure): plan, verdict, pose, rover description, map model, geometry;
- ``linkio/``: both ends of the wire, serial and CAN (docs/linkio.md);
- ``http/``: the HTTP stack of the gate and the live view, and its bind and token policy;
- ``runtime/``: real-time scheduling, stall detection (docs/realtime.md);
- ``cli/``: the ``rover`` command host and the ``main()`` of the programs ``ros2 run``
  starts.

The pure folders import none of the other four (tests/test_layers.py). The names below
are the pure folders' most used ones, imported on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.errors import (
    DecodeError,
    DescriptionError,
    EncodeError,
    MapError,
    PlanError,
    ProtoError,
    SpecError,
)
from firmware_proto.lazyexports import lazy_exports

if TYPE_CHECKING:
    from firmware_proto.model.plan import Goal, Plan, PlanStep, validate_plan
    from firmware_proto.model.rover import RoverDescription, load_rover
    from firmware_proto.model.worldmap import WorldMap, list_maps, load_map
    from firmware_proto.wire.canmap import CanDecoder, CanFrame, can_id, encode_can, split_can_id
    from firmware_proto.wire.counters import RxCounters
    from firmware_proto.wire.framing import (
        Frame,
        FrameDecoder,
        FrameEncoder,
        encode_frame,
        encode_raw_frame,
    )
    from firmware_proto.wire.message import Message
    from firmware_proto.wire.messages import PROTOCOL_VERSION, SCHEMA_HASH

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "firmware_proto.wire.canmap": (
            "CanDecoder",
            "CanFrame",
            "can_id",
            "encode_can",
            "split_can_id",
        ),
        "firmware_proto.wire.counters": ("RxCounters",),
        "firmware_proto.wire.framing": (
            "Frame",
            "FrameDecoder",
            "FrameEncoder",
            "encode_frame",
            "encode_raw_frame",
        ),
        "firmware_proto.wire.message": ("Message",),
        "firmware_proto.wire.messages": ("PROTOCOL_VERSION", "SCHEMA_HASH"),
        "firmware_proto.model.plan": ("Goal", "Plan", "PlanStep", "validate_plan"),
        "firmware_proto.model.rover": ("RoverDescription", "load_rover"),
        "firmware_proto.model.worldmap": ("WorldMap", "list_maps", "load_map"),
    },
)

__all__ = [
    "PROTOCOL_VERSION",
    "SCHEMA_HASH",
    "CanDecoder",
    "CanFrame",
    "DecodeError",
    "DescriptionError",
    "EncodeError",
    "Frame",
    "FrameDecoder",
    "FrameEncoder",
    "Goal",
    "MapError",
    "Message",
    "Plan",
    "PlanError",
    "PlanStep",
    "ProtoError",
    "RoverDescription",
    "RxCounters",
    "SpecError",
    "WorldMap",
    "can_id",
    "encode_can",
    "encode_frame",
    "encode_raw_frame",
    "list_maps",
    "load_map",
    "load_rover",
    "split_can_id",
    "validate_plan",
]

"""The base of the stack, which every other part may import, and which imports none of
them (docs/architecture.md, Parts and layers).

Its modules are pure (no I/O, no threads, no sockets, no ROS): the motor controller's
wire protocol generated from ``protocol.toml`` (messages, serial framing, CAN mapping;
docs/protocol.md), the plan, the verdict and the pose, the rover description, the map
model and the geometry helpers, the bind and token policy of our HTTP servers. The
names below are theirs.

Beside them, four sub-packages do I/O, and no pure module imports them:
``firmware_proto.linkio`` (both ends of the wire, serial and CAN; docs/linkio.md),
``firmware_proto.httpserve`` (the HTTP stack of the gate and the live view),
``firmware_proto.runtime`` (real-time scheduling, stall detection; docs/realtime.md) and
``firmware_proto.cli`` (the ``rover`` command host and the ``main()`` of the programs
``ros2 run`` starts). ``c/`` holds the C codec and the firmware core (docs/firmware.md).
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
    from firmware_proto.canmap import CanDecoder, CanFrame, can_id, encode_can, split_can_id
    from firmware_proto.counters import RxCounters
    from firmware_proto.framing import (
        Frame,
        FrameDecoder,
        FrameEncoder,
        encode_frame,
        encode_raw_frame,
    )
    from firmware_proto.message import Message
    from firmware_proto.messages import PROTOCOL_VERSION, SCHEMA_HASH
    from firmware_proto.plan import Goal, Plan, PlanStep, validate_plan
    from firmware_proto.rover import RoverDescription, load_rover
    from firmware_proto.worldmap import WorldMap, list_maps, load_map

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "firmware_proto.canmap": ("CanDecoder", "CanFrame", "can_id", "encode_can", "split_can_id"),
        "firmware_proto.counters": ("RxCounters",),
        "firmware_proto.framing": (
            "Frame",
            "FrameDecoder",
            "FrameEncoder",
            "encode_frame",
            "encode_raw_frame",
        ),
        "firmware_proto.message": ("Message",),
        "firmware_proto.messages": ("PROTOCOL_VERSION", "SCHEMA_HASH"),
        "firmware_proto.plan": ("Goal", "Plan", "PlanStep", "validate_plan"),
        "firmware_proto.rover": ("RoverDescription", "load_rover"),
        "firmware_proto.worldmap": ("WorldMap", "list_maps", "load_map"),
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

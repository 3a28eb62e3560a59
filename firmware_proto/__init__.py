"""The rover motor-controller wire protocol: messages, serial framing, CAN mapping,
the plan schema and the rover description. Pure code, no I/O; imports nothing else of
this project. See docs/protocol.md."""

from firmware_proto.canmap import CanDecoder, CanFrame, can_id, encode_can, split_can_id
from firmware_proto.counters import RxCounters
from firmware_proto.errors import (
    DecodeError,
    DescriptionError,
    EncodeError,
    PlanError,
    ProtoError,
    SpecError,
)
from firmware_proto.framing import Frame, FrameDecoder, FrameEncoder, encode_frame, encode_raw_frame
from firmware_proto.message import Message
from firmware_proto.messages import PROTOCOL_VERSION, SCHEMA_HASH
from firmware_proto.plan import Goal, Plan, PlanStep, validate_plan
from firmware_proto.rover import RoverDescription, load_rover

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
    "Message",
    "Plan",
    "PlanError",
    "PlanStep",
    "ProtoError",
    "RoverDescription",
    "RxCounters",
    "SpecError",
    "can_id",
    "encode_can",
    "encode_frame",
    "encode_raw_frame",
    "load_rover",
    "split_can_id",
    "validate_plan",
]

"""CAN mapping: message id and node id to 11-bit identifiers, payloads as is.

``identifier = msg_id << CAN_NODE_BITS | node`` (docs/protocol.md, "CAN mapping"): the
message id in the high bits makes identifier order the priority order, so every STOP
wins arbitration whatever the node ids. Node 0 is broadcast (host to controllers). Pure
functions and a counting decoder; the bus I/O lives in :mod:`firmware_proto.linkio`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from firmware_proto.errors import EncodeError
from firmware_proto.wire.counters import RxCounters
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BROADCAST_NODE, CAN_NODE_BITS, DECODERS, LENGTHS

__all__ = [
    "MAX_NODE",
    "NODE_MASK",
    "CanDecoder",
    "CanFrame",
    "can_id",
    "encode_can",
    "split_can_id",
]

logger = logging.getLogger(__name__)

NODE_MASK = (1 << CAN_NODE_BITS) - 1
MAX_NODE = NODE_MASK


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One decoded CAN frame: the node id from the identifier and the message."""

    node: int
    message: Message


def can_id(msg_id: int, node: int) -> int:
    """11-bit identifier of message ``msg_id`` for ``node``; EncodeError for a node outside
    0..15 or a msg_id outside 0..127."""
    if not 0 <= node <= MAX_NODE:
        raise EncodeError(f"CAN node id {node} outside 0..{MAX_NODE}", field="node")
    if not 0 <= msg_id <= 0x7FF >> CAN_NODE_BITS:
        raise EncodeError(f"message id {msg_id} does not fit an 11-bit identifier", field="msg_id")
    return (msg_id << CAN_NODE_BITS) | node


def split_can_id(arbitration_id: int) -> tuple[int, int]:
    """``(msg_id, node)`` of an 11-bit identifier."""
    return arbitration_id >> CAN_NODE_BITS, arbitration_id & NODE_MASK


def encode_can(message: Message, node: int, strict: bool = True) -> tuple[int, bytes]:
    """``(arbitration_id, data)`` of one message for ``node``; EncodeError naming a field or
    the node id out of range."""
    if node == BROADCAST_NODE and message.DIRECTION != "host_to_controller":
        raise EncodeError(
            f"{message.NAME} cannot be broadcast (node 0 is host to controller only)",
            message=message.NAME,
            field="node",
        )
    return can_id(message.MSG_ID, node), message.pack(strict)


class CanDecoder:
    """Decodes CAN frames into messages, counting what it drops (:attr:`counters`)."""

    def __init__(self) -> None:
        self.counters = RxCounters()

    def decode(
        self,
        arbitration_id: int,
        data: bytes,
        *,
        is_extended: bool = False,
        is_remote: bool = False,
    ) -> CanFrame | None:
        """The message in one frame, or ``None`` (counted) if it is not a valid one."""
        counters = self.counters
        if is_extended or is_remote or arbitration_id > 0x7FF:
            counters.not_classic += 1
            logger.debug("dropped non-classic CAN frame 0x%X", arbitration_id)
            return None
        msg_id = arbitration_id >> CAN_NODE_BITS
        length = LENGTHS.get(msg_id)
        if length is None:
            counters.unknown_id += 1
            logger.debug("dropped CAN frame with unknown id 0x%03X", arbitration_id)
            return None
        if len(data) != length:
            counters.bad_length += 1
            logger.debug("dropped CAN frame 0x%03X with %d bytes", arbitration_id, len(data))
            return None
        message = DECODERS[msg_id](bytes(data))
        if message is None:
            counters.out_of_range += 1
            logger.debug("dropped CAN frame 0x%03X: value out of range", arbitration_id)
            return None
        counters.frames += 1
        return CanFrame(arbitration_id & NODE_MASK, message)

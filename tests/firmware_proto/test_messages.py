"""Payload codec: every message round-trips; encode names bad fields; decode drops
out-of-range values."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.errors import DecodeError, EncodeError
from firmware_proto.wire import messages
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    DECODERS,
    Command,
    Encoders,
    Heartbeat,
    Motion,
    PoseMsg,
    Stop,
)
from firmware_proto.wire.spec import MessageSpec

from .strategies import SPEC, any_message, message_of


@given(any_message(within_limits=False))
def test_every_message_round_trips_through_its_payload(msg: Message) -> None:
    payload = msg.pack(strict=False)
    assert len(payload) == msg.LENGTH
    assert type(msg).unpack(payload) == msg
    assert DECODERS[msg.MSG_ID](payload) == msg


@pytest.mark.parametrize("spec", SPEC.messages, ids=lambda m: m.name)
def test_each_type_has_a_generated_class_matching_the_spec(spec: MessageSpec) -> None:
    cls = messages.BY_NAME[spec.name]
    assert spec.id == cls.MSG_ID
    assert spec.length == cls.LENGTH
    assert tuple(f.name for f in spec.public_fields) == cls.FIELDS


def test_known_bytes_of_motion() -> None:
    # seq 0x0102, FWD, speed 30, distance 23000 (0x59D8), all little-endian.
    assert Motion(0x0102, Command.FWD, 30, 23000).pack() == bytes.fromhex("0201011ed859")


def test_known_bytes_of_bit_packed_pose() -> None:
    pose = PoseMsg(x_mm=-1, y_mm=1, yaw_ddeg=-1, sigma_cm=15, age_4ms=0xAB)
    value = int.from_bytes(pose.pack(), "little")
    assert value & 0xFFFFF == 0xFFFFF  # x = -1 in 20 bits
    assert (value >> 20) & 0xFFFFF == 1
    assert (value >> 40) & 0xFFF == 0xFFF  # yaw = -1 in 12 bits
    assert (value >> 52) & 0xF == 15
    assert value >> 56 == 0xAB


def test_signed_24_bit_extremes() -> None:
    enc = Encoders(0xFFFF, -(1 << 23), (1 << 23) - 1)
    assert Encoders.unpack(enc.pack()) == enc


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (Motion(70000, 1, 1, 1), "seq"),
        (Motion(1, 1, 61, 1), "speed"),
        (Motion(1, 5, 1, 1), "command"),
        (Motion(1, 1, 1, 30001), "distance"),
        (Motion(1, 1, 256, 1), "speed"),
        (Stop(0, 0), "stop_id"),
        (Stop(1, 9), "source"),
        (PoseMsg(0, 0, 1801, 0, 0), "yaw_ddeg"),
        (Encoders(0, 1 << 23, 0), "left"),
        (Motion(1, 1, 1.5, 1), "speed"),  # type: ignore[arg-type]
        (Motion(1, 1, "30", 1), "speed"),  # type: ignore[arg-type]
    ],
)
def test_encode_refuses_and_names_the_field(msg: Message, field: str) -> None:
    with pytest.raises(EncodeError) as info:
        msg.pack()
    assert info.value.field == field
    assert f"{msg.NAME}.{field}" in str(info.value)


def test_loose_encode_allows_values_beyond_limits_within_the_wire_range() -> None:
    # A test host must be able to send speed 61 so that the controller can NACK it...
    assert Motion.unpack(Motion(1, 1, 61, 30001).pack(strict=False)) == Motion(1, 1, 61, 30001)
    # ...but never a value the wire cannot carry.
    with pytest.raises(EncodeError, match="range"):
        Motion(1, 1, 256, 0).pack(strict=False)


def test_decode_drops_values_outside_the_wire_range() -> None:
    good = Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 7, 0, 0).pack()
    bad = bytes([5]) + good[1:]  # state 5 (3 bits) is not a ControllerState
    assert DECODERS[Heartbeat.MSG_ID](bad) is None
    with pytest.raises(DecodeError, match="outside"):
        Heartbeat.unpack(bad)


def test_strict_decode_checks_length() -> None:
    with pytest.raises(DecodeError, match="6"):
        Motion.unpack(b"\x00" * 5)


@given(st.data())
def test_describe_shows_enum_names(data: st.DataObject) -> None:
    msg = data.draw(message_of(SPEC.messages[[m.name for m in SPEC.messages].index("MOTION")]))
    text = msg.describe()
    assert text.startswith("MOTION ")
    assert f"command={Command(msg.command).name}" in text  # type: ignore[attr-defined]


def test_messages_are_immutable_values() -> None:
    msg = Motion(1, 1, 1, 1)
    with pytest.raises(AttributeError):
        msg.speed = 2  # type: ignore[misc]
    assert hash(msg) == hash(Motion(1, 1, 1, 1))
    assert msg != Stop(1, 1)

"""Our DDS bytes are ROS 2's: byte-equal to rosbags' ROS2_JAZZY CDR serializer.

rosbags is an implementation of the ROS 2 wire format that we did not write. For every
message type, with seeded non-trivial values (edge integers, infinities, multi-byte
UTF-8, empty and non-empty sequences, every alignment), our encoder produces exactly
its bytes, and each side decodes the other's.
"""

from __future__ import annotations

import random
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from bridge.rosport.dds import cdr_decode, cdr_encode, idl_type
from bridge.rosport.errors import MessageError
from bridge.rosport.msgs import (
    MESSAGE_TYPES,
    DiagnosticArray,
    DiagnosticStatus,
    Empty,
    Int16MultiArray,
    KeyValue,
    Message,
    MultiArrayDimension,
    MultiArrayLayout,
    String,
)
from tests.bridge.samples import from_rosbags, sample, to_rosbags

JAZZY = get_typestore(Stores.ROS2_JAZZY)
SEEDS = range(12)
CDR_LE_HEADER = b"\x00\x01\x00\x00"


def rosbags_cdr(msg: Message) -> bytes:
    return bytes(JAZZY.serialize_cdr(to_rosbags(msg, JAZZY), msg.ROS_TYPE))


@pytest.mark.parametrize("ros_type", sorted(MESSAGE_TYPES))
def test_cdr_bytes_equal_rosbags_for_every_type(ros_type: str) -> None:
    msg_type = MESSAGE_TYPES[ros_type]
    for seed in SEEDS:
        msg = sample(msg_type, seed)
        ours = cdr_encode(msg)
        assert ours == rosbags_cdr(msg), f"{ros_type} seed {seed}: {msg}"
        assert ours[:4] == CDR_LE_HEADER


@pytest.mark.parametrize("ros_type", sorted(MESSAGE_TYPES))
def test_each_side_decodes_the_other(ros_type: str) -> None:
    msg_type = MESSAGE_TYPES[ros_type]
    for seed in SEEDS:
        msg = sample(msg_type, seed)
        assert cdr_decode(msg_type, rosbags_cdr(msg)) == msg
        decoded = JAZZY.deserialize_cdr(cdr_encode(msg), ros_type)
        assert from_rosbags(decoded, msg_type) == msg
        # As Cyclone's writer sends it: zero-padded to a multiple of 4 bytes.
        padded = cdr_encode(msg) + b"\0" * (-len(cdr_encode(msg)) % 4)
        assert from_rosbags(JAZZY.deserialize_cdr(padded, ros_type), msg_type) == msg
        assert cdr_decode(msg_type, padded) == msg


def test_wheel_instruction_bytes_by_hand() -> None:
    # [FWD, speed 30, 23000 units] with the empty layout ROS 2 tools send.
    msg = Int16MultiArray(data=(1, 30, 23000))
    body = struct.pack("<II", 0, 0) + struct.pack("<I3h", 3, 1, 30, 23000)
    assert cdr_encode(msg) == CDR_LE_HEADER + body


def test_status_string_bytes_by_hand() -> None:
    assert cdr_encode(String("completed")) == CDR_LE_HEADER + struct.pack("<I", 10) + b"completed\0"


def test_empty_carries_rosidls_one_byte() -> None:
    assert cdr_encode(Empty()) == CDR_LE_HEADER + b"\x00"


def test_wire_types_are_final_structs_with_ros_dds_names() -> None:
    for ros_type, msg_type in MESSAGE_TYPES.items():
        idl = idl_type(msg_type)
        package, _, name = ros_type.split("/")
        assert idl.__idl_typename__ == f"{package}::msg::dds_::{name}_"
        assert idl.__idl_annotations__.get("extensibility") == "final"


@given(
    data=st.lists(st.integers(-(2**15), 2**15 - 1), max_size=40),
    labels=st.lists(st.text(st.characters(blacklist_characters="\x00"), max_size=12), max_size=3),
    offset=st.integers(0, 2**32 - 1),
)
def test_int16_multi_array_fuzz_equals_rosbags(
    data: list[int], labels: list[str], offset: int
) -> None:
    layout = MultiArrayLayout(
        dim=tuple(MultiArrayDimension(label, len(data), i) for i, label in enumerate(labels)),
        data_offset=offset,
    )
    msg = Int16MultiArray(layout=layout, data=data)
    assert cdr_encode(msg) == rosbags_cdr(msg)
    assert cdr_decode(Int16MultiArray, cdr_encode(msg)) == msg


@given(st.text(st.characters(blacklist_characters="\x00"), max_size=64))
def test_string_fuzz_equals_rosbags(text: str) -> None:
    assert cdr_encode(String(text)) == rosbags_cdr(String(text))


def test_diagnostics_with_many_statuses_equal_rosbags() -> None:
    rng = random.Random(7)
    statuses = tuple(
        DiagnosticStatus(
            level=rng.choice((DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)),
            name=f"rover/link{i}",
            message="ok" * i,
            hardware_id="rassor-mc",
            values=tuple(KeyValue(f"k{j}", str(rng.random())) for j in range(i)),
        )
        for i in range(6)
    )
    msg = DiagnosticArray(status=statuses)
    assert cdr_encode(msg) == rosbags_cdr(msg)


@pytest.mark.parametrize("ros_type", sorted(MESSAGE_TYPES))
def test_truncated_samples_raise_message_error(ros_type: str) -> None:
    msg_type = MESSAGE_TYPES[ros_type]
    data = cdr_encode(sample(msg_type, 3))
    for cut in range(len(data)):
        with pytest.raises(MessageError, match=f"cannot decode {ros_type}"):
            cdr_decode(msg_type, data[:cut])


@given(st.sampled_from(sorted(MESSAGE_TYPES)), st.binary(max_size=96))
def test_garbage_decodes_or_raises_message_error(ros_type: str, body: bytes) -> None:
    msg_type = MESSAGE_TYPES[ros_type]
    try:
        decoded = cdr_decode(msg_type, CDR_LE_HEADER + body)
    except MessageError:
        return
    assert isinstance(decoded, msg_type)


def test_xcdr2_samples_are_refused() -> None:
    xcdr2 = b"\x00\x07\x00\x00" + cdr_encode(String("hi"))[4:]
    with pytest.raises(MessageError, match="encapsulation 0007 is not plain CDR"):
        cdr_decode(String, xcdr2)

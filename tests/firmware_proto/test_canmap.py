"""CAN mapping: identifiers, priorities, round trips over a real python-can bus, and the
generated DBC decoding our frames in cantools (a peer we did not write)."""

from __future__ import annotations

import functools
import itertools

import can
import cantools
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.errors import EncodeError
from firmware_proto.wire import codegen
from firmware_proto.wire.canmap import CanDecoder, can_id, encode_can, split_can_id
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import MESSAGE_TYPES, Ack, Motion, Stop

from .strategies import SPEC, any_message

nodes = st.integers(1, 15)


def test_every_stop_beats_every_other_frame_whatever_the_nodes() -> None:
    stop_ids = [can_id(Stop.MSG_ID, n) for n in range(16)]
    others = [
        can_id(cls.MSG_ID, n)
        for cls in MESSAGE_TYPES.values()
        if cls is not Stop
        for n in range(16)
    ]
    assert max(stop_ids) < min(others)


def test_identifiers_are_ordered_by_priority_class() -> None:
    order = [p.name for p in SPEC.priorities]
    assert order == ["emergency", "motion", "status", "telemetry", "config"]
    worst_of_class: dict[str, list[int]] = {}
    for m in SPEC.messages:
        worst_of_class.setdefault(m.priority, []).append(can_id(m.id, 15))
    for better, worse in itertools.pairwise(order):
        assert max(worst_of_class[better]) < min(
            can_id(m.id, 0) for m in SPEC.messages if m.priority == worse
        )


@given(any_message(), nodes)
def test_can_round_trip(msg: Message, node: int) -> None:
    arb, data = encode_can(msg, node)
    assert arb <= 0x7FF and len(data) <= 8
    assert split_can_id(arb) == (msg.MSG_ID, node)
    frame = CanDecoder().decode(arb, data)
    assert frame is not None
    assert (frame.node, frame.message) == (node, msg)


def test_node_and_broadcast_rules() -> None:
    with pytest.raises(EncodeError, match="node"):
        encode_can(Stop(1, 0), 16)
    arb, _ = encode_can(Stop(1, 0), 0)  # broadcast STOP is allowed
    assert arb == 0
    with pytest.raises(EncodeError, match="broadcast"):
        encode_can(Ack(1, 0, 0, 0), 0)


def test_can_decoder_drops_and_counts() -> None:
    dec = CanDecoder()
    arb, data = encode_can(Motion(1, 1, 1, 1), 1)
    assert dec.decode(arb, data, is_extended=True) is None
    assert dec.decode(arb, data, is_remote=True) is None
    assert dec.decode(arb, data[:-1]) is None
    assert dec.decode(0x7F1, b"") is None
    assert dec.decode(can_id(Stop.MSG_ID, 1), b"\x00\x00\x00") is None
    counts = dec.counters
    assert (counts.not_classic, counts.bad_length, counts.unknown_id, counts.out_of_range) == (
        2,
        1,
        1,
        1,
    )
    assert counts.frames == 0


def test_frames_cross_a_real_python_can_virtual_bus() -> None:
    sent: list[Message] = [Stop(1, 0), Motion(7, 1, 30, 23000), Ack(7, 0, 0, 1)]
    with (
        can.Bus(interface="virtual", channel="proto-test", receive_own_messages=False) as tx,
        can.Bus(interface="virtual", channel="proto-test") as rx,
    ):
        for msg in sent:
            arb, data = encode_can(msg, 3)
            tx.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
        dec = CanDecoder()
        got = []
        for _ in sent:
            frame = rx.recv(timeout=2.0)
            assert frame is not None
            decoded = dec.decode(
                frame.arbitration_id,
                bytes(frame.data),
                is_extended=frame.is_extended_id,
                is_remote=frame.is_remote_frame,
            )
            assert decoded is not None
            got.append(decoded.message)
    assert got == sent


@functools.cache
def _load_dbc() -> cantools.database.can.Database:
    path = codegen.REPO_ROOT / "firmware_proto" / "wire" / "rover.dbc"
    db = cantools.database.load_file(str(path), strict=True)
    assert isinstance(db, cantools.database.can.Database)
    return db


@pytest.fixture
def dbc() -> cantools.database.can.Database:
    return _load_dbc()


def test_dbc_lists_every_message(dbc: cantools.database.can.Database) -> None:
    assert {m.name for m in dbc.messages} == {cls.NAME for cls in MESSAGE_TYPES.values()}


@given(any_message(within_limits=False))
def test_cantools_decodes_every_frame_we_send(msg: Message) -> None:
    db = _load_dbc()
    arb, data = encode_can(msg, 1, strict=False)
    decoded = db.decode_message(arb, data, decode_choices=False, scaling=False)
    assert decoded == msg.to_dict()
    # Physical values: raw * scale, as the spec says.
    spec = next(m for m in SPEC.messages if m.id == msg.MSG_ID)
    physical = db.decode_message(arb, data, decode_choices=False)
    assert isinstance(physical, dict)
    for f in spec.public_fields:
        assert physical[f.name] == pytest.approx(getattr(msg, f.name) * f.scale)


def test_cantools_encodes_what_we_decode(dbc: cantools.database.can.Database) -> None:
    motion = Motion(513, 3, 45, 12345)
    data = dbc.encode_message("MOTION", motion.to_dict(), scaling=False)
    frame = CanDecoder().decode(dbc.get_message_by_name("MOTION").frame_id, data)
    assert frame is not None and frame.message == motion


@pytest.mark.parametrize("node", [0, 16, -1, 2000])
def test_dbc_render_refuses_a_node_that_is_not_a_controller(node: int) -> None:
    from firmware_proto.wire.codegen.dbc import render_dbc

    with pytest.raises(EncodeError, match=rf"controller node id {node} outside 1\.\.15") as exc:
        render_dbc(SPEC, node)
    assert exc.value.field == "node"


@pytest.mark.parametrize("node", [1, 7, 15])
def test_dbc_for_any_controller_node_decodes_that_nodes_frames(node: int) -> None:
    from firmware_proto.wire.codegen.dbc import render_dbc

    db = cantools.database.load_string(render_dbc(SPEC, node), database_format="dbc", strict=True)
    assert isinstance(db, cantools.database.can.Database)
    motion = Motion(9, 1, 30, 23000)
    arb, data = encode_can(motion, node)
    assert db.decode_message(arb, data, decode_choices=False, scaling=False) == motion.to_dict()

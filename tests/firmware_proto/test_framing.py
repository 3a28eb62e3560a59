"""Serial framing: round trips under any chunking, and bad input of every kind is
dropped, counted and never lets an altered frame through."""

from __future__ import annotations

import itertools
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.wire import cobs
from firmware_proto.wire.framing import (
    MAX_ENCODED_BYTES,
    MAX_WIRE_BYTES,
    FrameDecoder,
    FrameEncoder,
    encode_frame,
    encode_raw_frame,
)
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Heartbeat, HostHeartbeat, Motion, Stop

from .strategies import any_message


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    edges = [0, *points, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(edges)]


def _decode_all(chunks: list[bytes], decoder: FrameDecoder | None = None) -> list[Message]:
    decoder = decoder or FrameDecoder()
    return [f.message for chunk in chunks for f in decoder.feed(chunk)]


@given(st.lists(any_message(), min_size=1, max_size=30), st.lists(st.integers(0, 10_000)))
def test_any_sequence_round_trips_under_any_chunking(msgs: list[Message], cuts: list[int]) -> None:
    stream = b"".join(encode_frame(m, i) for i, m in enumerate(msgs))
    decoder = FrameDecoder()
    assert _decode_all(_chunks(stream, cuts), decoder) == msgs
    assert decoder.counters.frames == len(msgs)
    assert decoder.counters.rejected == 0
    assert decoder.counters.lost == 0


@given(any_message())
def test_wire_frames_are_bounded_and_zero_free_inside(msg: Message) -> None:
    wire = encode_frame(msg)
    assert len(wire) <= MAX_WIRE_BYTES == 15
    assert wire[0] == 0 and wire[-1] == 0
    assert 0 not in wire[1:-1]


@given(
    st.lists(any_message(), min_size=2, max_size=12),
    st.integers(0, 11),
    st.binary(min_size=1, max_size=64),
)
def test_noise_between_frames_alters_nothing_and_loses_nothing_after_it(
    msgs: list[Message], where: int, noise: bytes
) -> None:
    frames = [encode_frame(m, i) for i, m in enumerate(msgs)]
    cut = where % (len(frames) + 1)
    stream = b"".join(frames[:cut]) + noise + b"".join(frames[cut:])
    # Every frame has a delimiter on both sides, so noise before or after it is flushed
    # as its own (rejected) run: nothing altered, nothing lost.
    assert _decode_all([stream]) == msgs


@given(
    st.lists(any_message(), min_size=3, max_size=12),
    st.integers(0, 1_000),
    st.integers(0, 7),
)
def test_a_bit_flip_loses_at_most_the_frame_it_hit(msgs: list[Message], pos: int, bit: int) -> None:
    frames = [encode_frame(m, i) for i, m in enumerate(msgs)]
    stream = bytearray(b"".join(frames))
    pos %= len(stream)
    stream[pos] ^= 1 << bit
    # Which frame owns the flipped byte?
    owner, start = 0, 0
    while start + len(frames[owner]) <= pos:
        start += len(frames[owner])
        owner += 1
    got = _decode_all([bytes(stream)])
    others = msgs[:owner] + msgs[owner + 1 :]
    assert got in (others, msgs)  # the hit frame is dropped, or survived a delimiter hit


def _idle_delimiters(stream: bytes) -> int:
    """Delimiters that close an empty run (after another delimiter, or first in the
    stream): the only bytes a decoder neither delivers nor drops."""
    return sum(1 for k, b in enumerate(stream) if b == 0 and (k == 0 or stream[k - 1] == 0))


@given(
    st.lists(any_message(), min_size=1, max_size=20),
    st.lists(st.tuples(st.integers(0, 10_000), st.binary(min_size=1, max_size=40)), max_size=6),
    st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)), max_size=6),
    st.lists(st.integers(0, 10_000), max_size=8),
)
def test_noise_inside_frames_and_byte_flips_never_deliver_an_altered_frame(
    msgs: list[Message],
    inserts: list[tuple[int, bytes]],
    flips: list[tuple[int, int]],
    cuts: list[int],
) -> None:
    """Noise inserted at any byte offset (inside frames too) and bytes flipped anywhere:
    every delivered frame is one that was sent, in order; every frame whose own bytes
    (both delimiters included) were untouched is recovered; every byte fed is delivered
    in a frame, counted as dropped, or an idle delimiter."""
    wires = [encode_frame(m, i) for i, m in enumerate(msgs)]
    clean = b"".join(wires)
    starts = list(itertools.accumulate((len(w) for w in wires), initial=0))
    corrupted = bytearray(clean)
    for pos, mask in flips:
        corrupted[pos % len(clean)] ^= mask
    noise_at: dict[int, bytes] = {}
    for pos, noise in inserts:
        at = pos % (len(clean) + 1)
        noise_at[at] = noise_at.get(at, b"") + noise
    stream = b"".join(noise_at.get(k, b"") + corrupted[k : k + 1] for k in range(len(clean) + 1))
    stream += b"\x00"  # the link goes on: close whatever run the noise left open

    def touched(j: int) -> bool:
        lo, hi = starts[j], starts[j + 1]  # the frame is clean[lo:hi], delimiters included
        return any(lo <= pos % len(clean) < hi for pos, _ in flips) or any(
            lo < at < hi for at in noise_at
        )

    decoder = FrameDecoder()
    got = [f for chunk in _chunks(stream, cuts) for f in decoder.feed(chunk)]

    # Nothing altered: each delivered frame is a sent one (message and frame counter),
    # delivered once and in the order sent.
    assert all(f.seq < len(msgs) and f.message == msgs[f.seq] for f in got), got
    seqs = [f.seq for f in got]
    assert seqs == sorted(set(seqs))
    # Nothing lost that the damage did not reach.
    assert {j for j in range(len(msgs)) if not touched(j)} <= set(seqs)
    # Every byte is accounted for, and the frame-counter gaps count the missing frames.
    counters = decoder.counters
    assert counters.bytes == len(stream)
    delivered_bytes = sum(len(wires[s]) - 1 for s in seqs)  # the run and its closing 0x00
    assert counters.dropped_bytes == len(stream) - delivered_bytes - _idle_delimiters(stream)
    assert (counters.dropped_bytes > 0) == (counters.rejected > 0)
    assert counters.frames == len(got)
    assert counters.lost == (seqs[-1] - seqs[0] + 1 - len(seqs) if seqs else 0)
    assert decoder._buf == b""


@given(st.binary(max_size=2_000), st.lists(st.integers(0, 10_000), max_size=20))
def test_random_bytes_never_raise_and_memory_stays_bounded(data: bytes, cuts: list[int]) -> None:
    decoder = FrameDecoder()
    for chunk in _chunks(data, cuts):
        decoder.feed(chunk)
        assert len(decoder._buf) <= MAX_ENCODED_BYTES
    assert decoder.counters.bytes == len(data)


def test_random_stream_then_valid_frames_recovers_them() -> None:
    rng = random.Random(7)
    noise = bytes(rng.randrange(256) for _ in range(100_000))
    frames = [Motion(i, 1, 10, 100) for i in range(50)]
    stream = noise + b"".join(encode_frame(m, i) for i, m in enumerate(frames))
    assert _decode_all([stream])[-50:] == frames


@given(st.lists(any_message(), min_size=2, max_size=10), st.randoms(use_true_random=False))
def test_reordered_frames_are_delivered_as_received_and_counted_lost(
    msgs: list[Message], rnd: random.Random
) -> None:
    frames = [encode_frame(m, i) for i, m in enumerate(msgs)]
    order = list(range(len(frames)))
    rnd.shuffle(order)
    decoder = FrameDecoder()
    got = _decode_all([b"".join(frames[i] for i in order)], decoder)
    assert got == [msgs[i] for i in order]  # each frame is whole; order is the link's
    if order != sorted(order):
        assert decoder.counters.lost > 0


def _counters_after(stream: bytes) -> dict[str, int]:
    decoder = FrameDecoder()
    decoder.feed(stream)
    return {k: v for k, v in decoder.counters.as_dict().items() if v and k not in ("bytes",)}


def test_each_kind_of_bad_frame_is_counted_by_its_reason() -> None:
    good = encode_frame(Stop(5, 0))
    body = cobs.decode(good[1:-1])
    assert body is not None
    bad_crc = bytearray(body)
    bad_crc[-1] ^= 0xFF
    cases = {
        "crc": b"\x00" + cobs.encode(bytes(bad_crc)) + b"\x00",
        "framing": b"\x00\x05\x01\x00",  # COBS code points past the end
        "oversize": b"\x00" + b"\x01" * (MAX_ENCODED_BYTES + 1) + b"\x00",
        "unknown_id": encode_raw_frame(0x7E, 0, b"\x01\x02"),
        "bad_length": encode_raw_frame(Stop.MSG_ID, 0, b"\x05\x00"),
        "out_of_range": encode_raw_frame(Stop.MSG_ID, 0, b"\x00\x00\x00"),  # stop_id 0
    }
    for reason, stream in cases.items():
        counts = _counters_after(stream)
        assert counts.get(reason) == 1, (reason, counts)
        assert counts.get("frames", 0) == 0
        assert counts["dropped_bytes"] > 0


def test_truncated_frame_is_dropped_when_the_next_delimiter_comes() -> None:
    whole = encode_frame(Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 42, 0, 0))
    decoder = FrameDecoder()
    assert decoder.feed(whole[:-4]) == []
    frames = decoder.feed(b"\x00" + whole)
    assert [f.message for f in frames] == [Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 42, 0, 0)]
    assert decoder.counters.rejected == 1


def test_oversize_run_without_delimiter_is_discarded_once_and_stream_recovers() -> None:
    decoder = FrameDecoder()
    for _ in range(100):
        assert decoder.feed(b"\x55" * 1000) == []
    assert decoder.counters.oversize == 1
    assert decoder.counters.dropped_bytes == 100_000
    assert [f.message for f in decoder.feed(encode_frame(Stop(3, 0)))] == [Stop(3, 0)]


def test_frame_encoder_counts_and_lost_frames_are_detected() -> None:
    enc = FrameEncoder()
    wires = [enc.encode(Stop(i + 1, 0)) for i in range(300)]
    decoder = FrameDecoder()
    got = decoder.feed(b"".join(wires[:10] + wires[13:]))
    assert [f.seq for f in got[:3]] == [0, 1, 2]
    assert decoder.counters.lost == 3
    assert got[-1].seq == 299 & 0xFF


def test_reset_forgets_partial_frame_but_keeps_counters() -> None:
    decoder = FrameDecoder()
    decoder.feed(b"\x00" + b"\x03\x01")
    decoder.reset()
    assert [f.message for f in decoder.feed(encode_frame(Stop(9, 1)))] == [Stop(9, 1)]
    assert decoder.counters.bytes > 0


@pytest.mark.parametrize("size", [0, 1, 253, 254, 255, 508, 1000])
def test_cobs_round_trips_long_blocks(size: int) -> None:
    rng = random.Random(size)
    for data in (bytes(size), bytes(rng.randrange(1, 256) for _ in range(size))):
        out = cobs.encode(data)
        assert 0 not in out
        assert cobs.decode(out) == data


def test_a_raw_frame_with_a_bad_crc_is_dropped_as_crc() -> None:
    encoder = FrameEncoder()
    good = encoder.encode_raw(HostHeartbeat.MSG_ID, HostHeartbeat(5).pack())
    bad = encoder.encode_raw(HostHeartbeat.MSG_ID, HostHeartbeat(6).pack(), bad_crc=True)
    decoder = FrameDecoder()
    frames = decoder.feed(good + bad)
    assert [f.message for f in frames] == [HostHeartbeat(5)]
    assert (decoder.counters.crc, decoder.counters.rejected) == (1, 1)

"""Serial framing: ``0x00 | COBS(id, seq, payload, crc16) | 0x00`` (docs/protocol.md).

:func:`encode_frame` turns a message into wire bytes; :class:`FrameEncoder` adds the
per-sender frame counter. :class:`FrameDecoder` is fed arbitrary chunks of a byte
stream and returns the valid frames in them; it never raises on bad input, drops and
counts every bad frame by reason (:class:`~firmware_proto.wire.counters.RxCounters`) and
resynchronises at the next delimiter. Everything here is pure: no I/O, no threads.
"""

from __future__ import annotations

import itertools
import logging
from binascii import crc_hqx
from collections.abc import Callable
from typing import NamedTuple

from firmware_proto.wire import cobs
from firmware_proto.wire.counters import RxCounters
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import DECODERS, LENGTHS, MAX_PAYLOAD_BYTES

__all__ = [
    "DELIMITER",
    "MAX_ENCODED_BYTES",
    "MAX_FRAME_BYTES",
    "MAX_WIRE_BYTES",
    "Frame",
    "FrameDecoder",
    "FrameEncoder",
    "encode_frame",
    "encode_raw_frame",
]

logger = logging.getLogger(__name__)

DELIMITER = b"\x00"
_HEADER = 2  # id, seq
_CRC = 2
MAX_FRAME_BYTES = _HEADER + MAX_PAYLOAD_BYTES + _CRC
"""Largest frame before stuffing: id, seq, 8-byte payload, CRC."""
MAX_ENCODED_BYTES = cobs.max_encoded_length(MAX_FRAME_BYTES)
"""Largest run of bytes between two delimiters that can be a frame."""
MAX_WIRE_BYTES = MAX_ENCODED_BYTES + 2
"""Largest frame on the wire, both delimiters included (15 bytes)."""


class Frame(NamedTuple):
    """One decoded serial frame: the sender's frame counter and the message (a named tuple:
    one is built per received frame on the hot path)."""

    seq: int
    message: Message


_new_frame = tuple.__new__
_SLOTS: list[tuple[int, Callable[[bytes], Message | None]] | None] = [None] * 256
"""By id byte: (length of the unstuffed frame, payload decoder), or None if unknown."""
for _id, _length in LENGTHS.items():
    _SLOTS[_id] = (_length + _HEADER + _CRC, DECODERS[_id])
_CODE = [bytes((n + 1,)) for n in range(254)]
"""COBS code byte of a zero-free run of n bytes (n < 254; protocol frames are shorter)."""


def encode_raw_frame(msg_id: int, seq: int, payload: bytes, *, bad_crc: bool = False) -> bytes:
    """Frame arbitrary payload bytes (no field checks), for tests, fuzzing, replay and
    conformance: ``msg_id`` 0..255, the low 8 bits of ``seq``, ``payload`` as given; with
    ``bad_crc`` the CRC is inverted, so a receiver must drop the frame (*crc*)."""
    raw = bytes((msg_id, seq & 0xFF)) + payload
    crc = crc_hqx(raw, 0xFFFF) ^ (0xFFFF if bad_crc else 0)
    raw += crc.to_bytes(2, "big")
    if len(raw) >= 254:
        return DELIMITER + cobs.encode(raw) + DELIMITER
    # COBS inlined for short frames: each zero-free run becomes (length + 1) + run.
    pieces = [DELIMITER]
    for run in raw.split(DELIMITER):
        pieces += (_CODE[len(run)], run)
    pieces.append(DELIMITER)
    return b"".join(pieces)


def encode_frame(message: Message, seq: int = 0, strict: bool = True) -> bytes:
    """Wire bytes of one message, delimiters included, with the low 8 bits of the sender's
    frame counter ``seq``; ``strict``: semantic limits too (:meth:`Message.pack`).
    EncodeError, naming the field, for a value out of range."""
    return encode_raw_frame(message.MSG_ID, seq, message.pack(strict))


class FrameEncoder:
    """Encodes messages with an incrementing frame counter. Safe to share between threads
    (the counter is an ``itertools.count``, whose ``next`` is atomic)."""

    def __init__(self) -> None:
        self._counter = itertools.count()

    def encode(self, message: Message, strict: bool = True) -> bytes:
        """Wire bytes of ``message`` with the next frame counter value."""
        return encode_raw_frame(message.MSG_ID, next(self._counter), message.pack(strict))

    def encode_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> bytes:
        """Wire bytes of an unchecked frame (:func:`encode_raw_frame`), next frame counter."""
        return encode_raw_frame(msg_id, next(self._counter), payload, bad_crc=bad_crc)


class FrameDecoder:
    """Incremental decoder of a serial byte stream: feed it whatever the port returned; it
    keeps the partial frame between calls. Bad frames are dropped and counted in
    :attr:`counters` (detail at DEBUG). Memory is bounded: a run without delimiter longer
    than any frame is discarded up to the next delimiter."""

    def __init__(self) -> None:
        self.counters = RxCounters()
        self._buf = b""
        self._discarding = False
        self._last_seq: int | None = None

    def reset(self) -> None:
        """Forget the partial frame and the frame counter (a reconnect); counters are kept."""
        self._buf = b""
        self._discarding = False
        self._last_seq = None

    def feed(self, data: bytes) -> list[Frame]:
        """Consume ``data``; return the valid frames completed by it, in order."""
        counters = self.counters
        counters.bytes += len(data)
        if type(data) is not bytes:
            data = bytes(data)  # never keep a reference to the caller's mutable buffer
        parts = (self._buf + data).split(DELIMITER) if self._buf else data.split(DELIMITER)
        tail = parts.pop()
        if parts and self._discarding:
            # The end of a run already counted as oversize, and its closing delimiter, so
            # that the count does not depend on how the stream was chunked.
            self._discarding = False
            counters.dropped_bytes += len(parts[0]) + 1
            parts[0] = b""
        frames: list[Frame] = []
        last_seq = self._last_seq
        lost = 0
        # Hot path, inlined: a valid frame costs no function call but its payload
        # decoder. Anything unusual goes to _reject, which finds and counts the reason.
        for part in parts:
            if not part:
                continue
            n = len(part)
            raw: bytes | None = None
            if n <= MAX_ENCODED_BYTES:  # COBS decode; short blocks hold no 0xFF run
                pieces = []
                i = 0
                while i < n:
                    end = i + part[i]
                    if end > n:
                        break
                    pieces.append(part[i + 1 : end])
                    i = end
                else:
                    raw = b"\x00".join(pieces)
            slot = _SLOTS[raw[0]] if raw and not crc_hqx(raw, 0xFFFF) else None
            message = slot[1](raw[2:-2]) if slot and len(raw) == slot[0] else None  # type: ignore[arg-type,index]
            if message is None:
                self._reject(part, raw)
                continue
            seq = raw[1]  # type: ignore[index]
            if last_seq is not None and (seq - last_seq - 1) & 0xFF:
                lost += (seq - last_seq - 1) & 0xFF
            last_seq = seq
            frames.append(_new_frame(Frame, (seq, message)))
        self._last_seq = last_seq
        if frames:
            counters.frames += len(frames)
        if lost:
            counters.lost += lost
        if len(tail) > MAX_ENCODED_BYTES:
            self._drop_run(tail)
            tail = b""
        self._buf = tail
        return frames

    def _drop_run(self, run: bytes) -> None:
        if not self._discarding:
            self.counters.oversize += 1
            self._discarding = True
            logger.debug("dropped oversize run of %d+ bytes without delimiter", len(run))
        self.counters.dropped_bytes += len(run)

    def _reject(self, part: bytes, raw: bytes | None) -> None:
        """Count why ``part`` (and ``raw``, its COBS decoding if valid) is not a frame."""
        if len(part) > MAX_ENCODED_BYTES:
            reason = "oversize"
        elif raw is None or len(raw) < _HEADER + _CRC:
            reason = "framing"
        elif crc_hqx(raw, 0xFFFF):
            reason = "crc"
        elif raw[0] not in LENGTHS:
            reason = "unknown_id"
        elif len(raw) != LENGTHS[raw[0]] + _HEADER + _CRC:
            reason = "bad_length"
        else:
            reason = "out_of_range"
        counters = self.counters
        setattr(counters, reason, getattr(counters, reason) + 1)
        counters.dropped_bytes += len(part) + 1
        logger.debug("dropped frame (%s): %s", reason, part.hex())

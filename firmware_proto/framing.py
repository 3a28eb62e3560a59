"""Serial framing: ``0x00 | COBS(id, seq, payload, crc16) | 0x00`` (docs/protocol.md).

:func:`encode_frame` turns a message into wire bytes; :class:`FrameEncoder` adds the
per-sender frame counter. :class:`FrameDecoder` is fed arbitrary chunks of a byte
stream and returns the valid frames in them; it never raises on bad input, drops and
counts every bad frame by reason (:class:`~firmware_proto.counters.RxCounters`) and
resynchronises at the next delimiter. Everything here is pure: no I/O, no threads.
"""

from __future__ import annotations

import itertools
import logging
from binascii import crc_hqx
from dataclasses import dataclass

from firmware_proto import cobs
from firmware_proto.counters import RxCounters
from firmware_proto.message import Message
from firmware_proto.messages import DECODERS, LENGTHS, MAX_PAYLOAD_BYTES

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


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded serial frame: the sender's frame counter and the message."""

    seq: int
    message: Message


def encode_raw_frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    """Frame arbitrary payload bytes (no field checks): for tests, fuzzing and replay.

    Args:
        msg_id: message id byte, 0..255.
        seq: frame counter; only its low 8 bits are sent.
        payload: payload bytes, sent as given.
    """
    raw = bytes((msg_id, seq & 0xFF)) + payload
    raw += crc_hqx(raw, 0xFFFF).to_bytes(2, "big")
    return DELIMITER + cobs.encode(raw) + DELIMITER


def encode_frame(message: Message, seq: int = 0, strict: bool = True) -> bytes:
    """Wire bytes of one message, delimiters included.

    Args:
        message: the message to send.
        seq: the sender's frame counter (low 8 bits sent).
        strict: enforce semantic limits too (see :meth:`Message.pack`).

    Raises:
        EncodeError: a field is out of range; the error names it.
    """
    return encode_raw_frame(message.MSG_ID, seq, message.pack(strict))


class FrameEncoder:
    """Encodes messages with an incrementing frame counter. Safe to share between threads
    (the counter is an ``itertools.count``, whose ``next`` is atomic)."""

    def __init__(self) -> None:
        self._counter = itertools.count()

    def encode(self, message: Message, strict: bool = True) -> bytes:
        """Wire bytes of ``message`` with the next frame counter value."""
        return encode_raw_frame(message.MSG_ID, next(self._counter), message.pack(strict))


class FrameDecoder:
    """Incremental decoder of a serial byte stream.

    Feed it whatever the port returned; it keeps the partial frame between calls. Bad
    frames are dropped and counted in :attr:`counters`, per-frame detail is logged at
    DEBUG. Memory is bounded: a run without delimiter longer than any frame is discarded
    up to the next delimiter.
    """

    def __init__(self) -> None:
        self.counters = RxCounters()
        self._buf = b""
        self._discarding = False
        self._last_seq: int | None = None

    def reset(self) -> None:
        """Forget the partial frame and the frame counter (e.g. after a reconnect);
        counters keep their values."""
        self._buf = b""
        self._discarding = False
        self._last_seq = None

    def feed(self, data: bytes) -> list[Frame]:
        """Consume ``data``; return the valid frames completed by it, in order."""
        counters = self.counters
        counters.bytes += len(data)
        buf = self._buf + bytes(data)
        if DELIMITER not in buf:
            if len(buf) > MAX_ENCODED_BYTES:
                self._drop_run(buf)
                buf = b""
            self._buf = buf
            return []
        *parts, tail = buf.split(DELIMITER)
        frames: list[Frame] = []
        for part in parts:
            if self._discarding:
                # The end of a run that was already counted as oversize.
                self._discarding = False
                counters.dropped_bytes += len(part)
            elif part:
                frame = self._decode(part)
                if frame is not None:
                    frames.append(frame)
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

    def _reject(self, part: bytes, reason: str) -> None:
        counters = self.counters
        setattr(counters, reason, getattr(counters, reason) + 1)
        counters.dropped_bytes += len(part) + 1
        logger.debug("dropped frame (%s): %s", reason, part.hex())

    def _decode(self, part: bytes) -> Frame | None:
        if len(part) > MAX_ENCODED_BYTES:
            self._reject(part, "oversize")
            return None
        raw = cobs.decode(part)
        if raw is None or len(raw) < _HEADER + _CRC:
            self._reject(part, "framing")
            return None
        if crc_hqx(raw, 0xFFFF):
            self._reject(part, "crc")
            return None
        msg_id = raw[0]
        length = LENGTHS.get(msg_id)
        if length is None:
            self._reject(part, "unknown_id")
            return None
        if len(raw) != length + _HEADER + _CRC:
            self._reject(part, "bad_length")
            return None
        message = DECODERS[msg_id](raw[_HEADER:-_CRC])
        if message is None:
            self._reject(part, "out_of_range")
            return None
        seq = raw[1]
        if self._last_seq is not None:
            self.counters.lost += (seq - self._last_seq - 1) & 0xFF
        self._last_seq = seq
        self.counters.frames += 1
        return Frame(seq, message)

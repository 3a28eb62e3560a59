"""Render the shared test vectors (``firmware_proto/wire/vectors/*.json``) from the spec model.

The vectors are the contract between the Python codec and the C reference codec: both
must produce and accept exactly these bytes and count exactly these drops. They are
derived from the spec with a seeded generator (:data:`SEED`), reproducible and
stale-checked like every generated file. To stay independent of the codec under test,
nothing here imports the generated ``messages.py`` or the decoders: payloads are packed
by :func:`pack_fields` from the field layout, and the expected frames and counters come
from :class:`ReferenceDecoder`, a plain model of docs/protocol.md ("Serial framing").
Only the hand-written COBS and the standard library's CRC are shared.

Files: ``messages.json`` (valid instances at every field's extremes and seeded values,
with their serial frames and CAN frames for several nodes; encode errors naming the
field), ``serial_streams.json`` (chunked streams, clean and damaged every way, with the
frames and counters a decoder must report), ``can_frames.json`` (the same for CAN).
"""

from __future__ import annotations

import itertools
import json
import random
from binascii import crc_hqx
from collections.abc import Callable
from typing import Any

from firmware_proto.wire import cobs
from firmware_proto.wire.spec import FieldSpec, MessageSpec, ProtocolSpec

__all__ = [
    "COUNTER_NAMES",
    "SEED",
    "VECTOR_TARGETS",
    "ReferenceDecoder",
    "pack_fields",
    "render_can_vectors",
    "render_message_vectors",
    "render_serial_vectors",
    "unpack_fields",
]

SEED = 0x5EED_0C0D
"""Seed of every random choice in the vectors; change it only on purpose."""

COUNTER_NAMES = (
    "frames",
    "bytes",
    "dropped_bytes",
    "framing",
    "oversize",
    "crc",
    "unknown_id",
    "bad_length",
    "out_of_range",
    "lost",
    "not_classic",
)
"""Counter names, as in ``firmware_proto.wire.counters.RxCounters`` and C ``rp_counters_t``."""

_BANNER = (
    "GENERATED from firmware_proto/wire/protocol.toml by firmware_proto/wire/codegen/vectors.py "
    "(`rover frame generate`). Do not edit."
)

Fields = dict[str, int]


# ------------------------------------------------------------------ reference model


def pack_fields(msg: MessageSpec, values: Fields) -> bytes:
    """Payload bytes of ``values`` (no range checks): LSB-first little-endian bit packing."""
    word = 0
    for f in msg.public_fields:
        word |= (values[f.name] & ((1 << f.bits) - 1)) << f.start_bit
    return word.to_bytes(msg.length, "little")


def unpack_fields(msg: MessageSpec, payload: bytes) -> Fields | None:
    """Field values of a payload of the right length; ``None`` if one is out of range."""
    word = int.from_bytes(payload, "little")
    values: Fields = {}
    for f in msg.public_fields:
        raw = (word >> f.start_bit) & ((1 << f.bits) - 1)
        if f.signed and raw >> (f.bits - 1):
            raw -= 1 << f.bits
        if not f.min <= raw <= f.max:
            return None
        values[f.name] = raw
    return values


def frame_bytes(msg_id: int, seq: int, payload: bytes) -> bytes:
    """``0x00 | COBS(id, seq, payload, crc16 big-endian) | 0x00``."""
    raw = bytes((msg_id, seq & 0xFF)) + payload
    raw += crc_hqx(raw, 0xFFFF).to_bytes(2, "big")
    return b"\x00" + cobs.encode(raw) + b"\x00"


class ReferenceDecoder:
    """The serial decoding rules, modelled byte by byte from the spec.

    Between delimiters a run of at most ``max_run`` bytes is a frame candidate, checked in
    order: COBS and at least 4 bytes (framing), CRC, known id, length, field ranges; a
    rejected candidate drops its bytes and its closing delimiter. A run that grows beyond
    ``max_run`` is oversize: rejected when its delimiter arrives in the same chunk, else
    dropped (counted once) at the chunk's end with the rest of it, delimiter included.
    Empty runs are ignored; gaps in seq count as lost.
    """

    def __init__(self, spec: ProtocolSpec) -> None:
        self._by_id = {m.id: m for m in spec.messages}
        max_frame = 2 + int(spec.framing["max_payload_bytes"]) + 2
        self.max_run = cobs.max_encoded_length(max_frame)
        self.counters = dict.fromkeys(COUNTER_NAMES, 0)
        self._run = bytearray()
        self._discarding = False
        self._last_seq: int | None = None

    def feed(self, chunk: bytes) -> list[dict[str, Any]]:
        """Decode one chunk; the frames it completes as ``{"id", "seq", "fields"}``."""
        c = self.counters
        frames = []
        for byte in chunk:
            c["bytes"] += 1
            if byte:
                self._run.append(byte)
                continue
            run, self._run = bytes(self._run), bytearray()
            if self._discarding:
                self._discarding = False
                c["dropped_bytes"] += len(run) + 1
            elif len(run) > self.max_run:
                self._drop(run, "oversize")
            elif run:
                frame = self._check(run)
                if frame is not None:
                    frames.append(frame)
        if len(self._run) > self.max_run:
            if not self._discarding:
                c["oversize"] += 1
                self._discarding = True
            c["dropped_bytes"] += len(self._run)
            self._run = bytearray()
        return frames

    def _drop(self, run: bytes, reason: str) -> None:
        self.counters[reason] += 1
        self.counters["dropped_bytes"] += len(run) + 1

    def _check(self, run: bytes) -> dict[str, Any] | None:
        raw = cobs.decode(run)
        if raw is None or len(raw) < 4:
            self._drop(run, "framing")
            return None
        if crc_hqx(raw[:-2], 0xFFFF) != int.from_bytes(raw[-2:], "big"):
            self._drop(run, "crc")
            return None
        msg = self._by_id.get(raw[0])
        if msg is None:
            self._drop(run, "unknown_id")
            return None
        if len(raw) != msg.length + 4:
            self._drop(run, "bad_length")
            return None
        values = unpack_fields(msg, raw[2:-2])
        if values is None:
            self._drop(run, "out_of_range")
            return None
        seq = raw[1]
        if self._last_seq is not None:
            self.counters["lost"] += (seq - self._last_seq - 1) % 256
        self._last_seq = seq
        self.counters["frames"] += 1
        return {"id": msg.id, "seq": seq, "fields": values}


def _can_decode(
    spec: ProtocolSpec, counters: dict[str, int], frame: tuple[int, bool, bool, bytes]
) -> dict[str, Any] | None:
    can_id, ext, rtr, data = frame
    bits = int(spec.framing["can_node_bits"])
    if ext or rtr or can_id > 0x7FF:
        counters["not_classic"] += 1
        return None
    msg = {m.id: m for m in spec.messages}.get(can_id >> bits)
    if msg is None:
        counters["unknown_id"] += 1
        return None
    if len(data) != msg.length:
        counters["bad_length"] += 1
        return None
    values = unpack_fields(msg, data)
    if values is None:
        counters["out_of_range"] += 1
        return None
    counters["frames"] += 1
    return {"node": can_id & ((1 << bits) - 1), "id": msg.id, "fields": values}


# ------------------------------------------------------------------ instances


def _bounds(f: FieldSpec, within_limit: bool) -> tuple[int, int]:
    return f.limit if (within_limit and f.limit) else (f.min, f.max)


def _within_limits(msg: MessageSpec, values: Fields) -> bool:
    return all(
        f.limit is None or f.limit[0] <= values[f.name] <= f.limit[1] for f in msg.public_fields
    )


def _instances(msg: MessageSpec, rng: random.Random) -> list[tuple[str, Fields]]:
    pub = msg.public_fields
    candidates: list[tuple[str, Fields]] = [
        ("min", {f.name: f.min for f in pub}),
        ("max", {f.name: f.max for f in pub}),
        ("limit_lo", {f.name: _bounds(f, True)[0] for f in pub}),
        ("limit_hi", {f.name: _bounds(f, True)[1] for f in pub}),
        ("zero", {f.name: min(max(0, f.min), f.max) for f in pub}),
        ("minus_one", {f.name: -1 if f.min <= -1 else f.min for f in pub}),
        # Alternate extremes, so each field's extreme meets its neighbours' opposite one.
        ("alternate", {f.name: (f.min, f.max)[i % 2] for i, f in enumerate(pub)}),
        ("alternate_2", {f.name: (f.max, f.min)[i % 2] for i, f in enumerate(pub)}),
    ]
    for k in range(3):
        candidates.append((f"random_{k}", {f.name: rng.randint(*_bounds(f, True)) for f in pub}))
    out: list[tuple[str, Fields]] = []
    seen: list[Fields] = []
    for label, values in candidates:
        if values not in seen:
            seen.append(values)
            out.append((label, values))
    return out


def _can_entry(spec: ProtocolSpec, msg: MessageSpec, node: int, payload: bytes) -> dict[str, Any]:
    can_id = (msg.id << int(spec.framing["can_node_bits"])) | node
    return {"node": node, "can_id": can_id, "data": payload.hex()}


def _message_vectors(spec: ProtocolSpec) -> list[dict[str, Any]]:
    out = []
    broadcast = int(spec.framing["broadcast_node"])
    default = int(spec.framing["default_node"])
    max_node = (1 << int(spec.framing["can_node_bits"])) - 1
    for msg in spec.messages:
        rng = _rng(f"messages:{msg.name}")  # per message: an edit changes its vectors only
        for label, values in _instances(msg, rng):
            seq = rng.choice((0, 255, rng.randrange(256)))
            payload = pack_fields(msg, values)
            nodes = [default, rng.choice([n for n in range(1, max_node + 1) if n != default])]
            if msg.direction == "host_to_controller":
                nodes.append(broadcast)
            out.append(
                {
                    "name": msg.name,
                    "id": msg.id,
                    "label": label,
                    "strict": _within_limits(msg, values),
                    "fields": values,
                    "seq": seq,
                    "payload": payload.hex(),
                    "serial": frame_bytes(msg.id, seq, payload).hex(),
                    "can": [_can_entry(spec, msg, n, payload) for n in nodes],
                }
            )
    return out


def _error(
    msg: MessageSpec,
    values: Fields,
    strict: bool,
    kind: str,
    field: str,
    *,
    node: int | None = None,
) -> dict[str, Any]:
    """An expected encode error; with ``node`` the message is encoded for CAN."""
    entry: dict[str, Any] = {
        "name": msg.name,
        "fields": values,
        "strict": strict,
        "transport": "serial" if node is None else "can",
        "kind": kind,
        "field": field,
    }
    if node is not None:
        entry["node"] = node
    return entry


def _encode_errors(spec: ProtocolSpec) -> list[dict[str, Any]]:
    out = []
    default = int(spec.framing["default_node"])
    max_node = (1 << int(spec.framing["can_node_bits"])) - 1
    for msg in spec.messages:
        rng = _rng(f"errors:{msg.name}")
        pub = msg.public_fields
        valid = {f.name: rng.randint(*_bounds(f, True)) for f in pub}
        for i, f in enumerate(pub):
            # Just outside the wire range, and far outside the field's C type.
            for bad in (f.min - 1, f.max + 1, f.min - (1 << 40), f.max + (1 << 40)):
                if f.min <= bad <= f.max:
                    continue
                if f.min - 1 <= bad <= f.max + 1 or rng.random() < 0.5:
                    out.append(_error(msg, {**valid, f.name: bad}, True, "range", f.name))
            if f.limit:
                lo, hi = f.limit
                for bad in (lo - 1, hi + 1):
                    if f.min <= bad <= f.max:
                        out.append(_error(msg, {**valid, f.name: bad}, True, "limit", f.name))
                # A later field out of its wire range wins over this limit: ranges first.
                for g in pub[i + 1 :]:
                    values = {**valid, f.name: hi + 1 if hi < f.max else lo - 1, g.name: g.max + 1}
                    if f.min <= values[f.name] <= f.max:
                        out.append(_error(msg, values, True, "range", g.name))
        # Two fields out of range: the first in wire order is named.
        if len(pub) >= 2:
            values = {**valid, pub[-1].name: pub[-1].max + 1, pub[0].name: pub[0].max + 1}
            out.append(_error(msg, values, False, "range", pub[0].name))
        # CAN: node checks come first, before any field.
        bad_fields = {**valid, pub[0].name: pub[0].max + 1} if pub else valid
        out.append(_error(msg, valid, True, "node", "node", node=max_node + 1))
        out.append(_error(msg, bad_fields, True, "node", "node", node=max_node + 1))
        if msg.direction != "host_to_controller":
            out.append(_error(msg, bad_fields, True, "broadcast", "node", node=0))
        if pub:
            out.append(_error(msg, bad_fields, True, "range", pub[0].name, node=default))
    return out


# ------------------------------------------------------------------ serial streams


def _random_frame(spec: ProtocolSpec, rng: random.Random, seq: int) -> bytes:
    msg = rng.choice(spec.messages)
    values = {f.name: rng.randint(*_bounds(f, True)) for f in msg.public_fields}
    return frame_bytes(msg.id, seq, pack_fields(msg, values))


def _valid_frames(spec: ProtocolSpec, rng: random.Random, n: int, seq0: int = 0) -> list[bytes]:
    return [_random_frame(spec, rng, seq0 + k) for k in range(n)]


def _split(data: bytes, rng: random.Random, pieces: int) -> list[bytes]:
    cuts = sorted(rng.sample(range(1, len(data)), min(pieces - 1, len(data) - 1)))
    edges = [0, *cuts, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(edges)]


def _out_of_range_payloads(msg: MessageSpec) -> list[tuple[str, bytes]]:
    """Payloads with one field just outside its wire range (but inside its bits)."""
    base = {f.name: f.min for f in msg.public_fields}
    out = []
    for f in msg.public_fields:
        for bad in (f.min - 1, f.max + 1):
            if f.type_min <= bad <= f.type_max and not f.min <= bad <= f.max:
                out.append((f"{f.name}={bad}", pack_fields(msg, {**base, f.name: bad})))
    return out


def _raw_frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    return frame_bytes(msg_id, seq, payload)


def _stream_cases(spec: ProtocolSpec, rng: random.Random) -> list[tuple[str, str, list[bytes]]]:
    by_name = {m.name: m for m in spec.messages}
    cases: list[tuple[str, str, list[bytes]]] = []

    def add(label: str, doc: str, chunks: list[bytes]) -> None:
        cases.append((label, doc, chunks))

    clean = b"".join(_valid_frames(spec, rng, 12))
    add("clean", "twelve valid frames in one chunk", [clean])
    add(
        "clean_bytewise",
        "the same kind of stream fed one byte at a time",
        list(bytes((b,)) for b in b"".join(_valid_frames(spec, rng, 6))),
    )
    add(
        "clean_random_chunks",
        "valid frames in random chunks",
        _split(b"".join(_valid_frames(spec, rng, 10)), rng, 7),
    )
    add(
        "empty_runs",
        "repeated delimiters between frames are ignored",
        [b"\x00\x00\x00" + b"\x00\x00".join(_valid_frames(spec, rng, 3)) + b"\x00\x00"],
    )
    add(
        "empty_chunks",
        "empty chunks change nothing",
        [b"", *_split(b"".join(_valid_frames(spec, rng, 3)), rng, 3), b""],
    )

    frames = _valid_frames(spec, rng, 4)
    add(
        "truncated_tail",
        "the last frame is cut short: it stays pending, nothing is counted",
        [b"".join(frames[:3]) + frames[3][: len(frames[3]) // 2]],
    )
    frames = _valid_frames(spec, rng, 4)
    add(
        "truncated_then_valid",
        "a frame cut short, then whole frames: the cut one is dropped",
        [frames[0] + frames[1][: len(frames[1]) - 4] + b"".join(frames[2:])],
    )
    frames = _valid_frames(spec, rng, 3)
    add(
        "truncated_no_leading_delimiter",
        "a stream starting in the middle of a frame",
        [frames[0][5:] + b"".join(frames[1:])],
    )

    for k in range(10):
        frames = _valid_frames(spec, rng, 5, seq0=rng.randrange(256))
        flipped = bytearray(b"".join(frames))
        pos = rng.randrange(len(flipped))
        flipped[pos] ^= 1 << rng.randrange(8)
        add(f"bit_flip_{k}", f"one bit flipped at byte {pos}", [bytes(flipped)])
    frames = _valid_frames(spec, rng, 3)
    hit = bytearray(frames[1])
    hit[-2] ^= 0x01  # the last CRC byte (or code), always inside the frame
    add("bit_flip_crc", "a corrupted CRC byte", [frames[0] + bytes(hit) + frames[2]])
    hit = bytearray(frames[1])
    hit[1] = 0x0E  # a COBS code running past the end of the frame
    add(
        "bad_cobs_code",
        "a COBS code byte pointing past the frame",
        [frames[0] + bytes(hit) + frames[2]],
    )

    garbage = bytes(rng.randrange(1, 256) for _ in range(40))
    frames = _valid_frames(spec, rng, 3)
    add(
        "oversize_one_chunk",
        "40 bytes without a delimiter inside one chunk",
        [frames[0] + garbage + b"".join(frames[1:])],
    )
    add(
        "oversize_split",
        "the same run split over chunks: dropped at the chunk end",
        [frames[0] + garbage[:20], garbage[20:] + b"".join(frames[1:])],
    )
    long_run = bytes(rng.randrange(1, 256) for _ in range(100))
    add(
        "oversize_many_chunks",
        "a 100-byte run over many chunks is counted once",
        [*_split(long_run, rng, 8), b"".join(_valid_frames(spec, rng, 2))],
    )
    add(
        "oversize_exact",
        "14 bytes between delimiters: one more than any frame",
        [b"\x00" + bytes(range(1, 15)) + b"\x00" + _valid_frames(spec, rng, 1)[0]],
    )
    add(
        "oversize_open_at_end",
        "a long run still open when the stream ends",
        [_valid_frames(spec, rng, 1)[0] + long_run[:30]],
    )

    frames = _valid_frames(spec, rng, 4)
    noise = bytes(rng.randrange(256) for _ in range(25))
    add(
        "garbage_between",
        "random bytes, zeros included, between frames",
        [frames[0] + frames[1] + noise + frames[2] + frames[3]],
    )
    add(
        "garbage_before",
        "line noise before the first frame (a reconnect)",
        [bytes(rng.randrange(1, 256) for _ in range(7)) + b"".join(_valid_frames(spec, rng, 2))],
    )

    # Any message with a payload will do; MOTION is the one a controller sees most.
    motion = by_name.get("MOTION") or max(spec.messages, key=lambda m: m.length)
    heartbeat = max(spec.messages, key=lambda m: m.length)
    add(
        "bad_length",
        "valid CRC, payload one byte short, one byte long, empty",
        [
            _raw_frame(motion.id, 0, bytes(motion.length - 1))
            + _raw_frame(motion.id, 1, bytes(range(1, motion.length + 2)))
            + _raw_frame(motion.id, 2, b"")
            + _valid_frames(spec, rng, 1, seq0=3)[0]
        ],
    )
    add(
        "too_long_for_a_frame",
        "a 9-byte payload: its stuffed frame is oversize",
        [_raw_frame(heartbeat.id, 0, bytes(range(1, 10))) + _valid_frames(spec, rng, 1, 1)[0]],
    )
    known = {m.id for m in spec.messages}
    unknown = [i for i in (5, 127, 128, 200, 255) if i not in known]
    add(
        "unknown_id",
        f"valid CRC, ids {unknown} not in the protocol",
        [
            b"".join(_raw_frame(i, k, b"\x01\x02\x03") for k, i in enumerate(unknown))
            + _valid_frames(spec, rng, 1, seq0=len(unknown))[0]
        ],
    )
    add(
        "too_short",
        "fewer than 4 bytes after unstuffing",
        [
            b"\x00\x01\x00"
            + b"\x00\x02\x08\x00"
            + b"\x00"
            + cobs.encode(b"\x08\x01\x02")
            + b"\x00"
            + _valid_frames(spec, rng, 1)[0]
        ],
    )
    for msg in spec.messages:
        bad = _out_of_range_payloads(msg)
        if not bad:
            continue
        stream = b"".join(_raw_frame(msg.id, k, p) for k, (_, p) in enumerate(bad))
        add(
            f"out_of_range_{msg.name.lower()}",
            "valid CRC, one field outside its range: " + ", ".join(label for label, _ in bad),
            [stream + _valid_frames(spec, rng, 1, seq0=len(bad))[0]],
        )

    add(
        "seq_gap",
        "seq 0, 1, 5, 6: three frames lost",
        [b"".join(_random_frame(spec, rng, s) for s in (0, 1, 5, 6))],
    )
    add(
        "seq_wrap",
        "seq 254, 255, 0, 1: the counter wraps, nothing lost",
        [b"".join(_random_frame(spec, rng, s) for s in (254, 255, 0, 1))],
    )
    add(
        "seq_repeat",
        "seq 7, 7: a repeated seq counts as 255 lost (a full wrap)",
        [b"".join(_random_frame(spec, rng, s) for s in (7, 7, 8))],
    )

    for k in range(12):
        frames = _valid_frames(spec, rng, rng.randint(4, 12), seq0=rng.randrange(256))
        parts: list[bytes] = []
        for whole in frames:
            action = rng.random()
            part = whole
            if action < 0.15:
                hit = bytearray(whole)
                hit[rng.randrange(len(hit))] ^= 1 << rng.randrange(8)
                part = bytes(hit)
            elif action < 0.25:
                part = whole[: rng.randrange(1, len(whole))]
            elif action < 0.35:
                part = whole + bytes(rng.randrange(256) for _ in range(rng.randint(1, 30)))
            elif action < 0.4:
                continue
            parts.append(part)
        stream = b"".join(parts)
        pieces = rng.choice((1, 3, len(stream) // 4 or 1, len(stream)))
        add(
            f"random_mix_{k}",
            "seeded mix of flips, cuts, garbage and losses, chunked",
            _split(stream, rng, pieces) if pieces > 1 else [stream],
        )
    return cases


def _serial_vectors(spec: ProtocolSpec, rng: random.Random) -> list[dict[str, Any]]:
    out = []
    for label, doc, chunks in _stream_cases(spec, rng):
        decoder = ReferenceDecoder(spec)
        frames = [frame for chunk in chunks for frame in decoder.feed(chunk)]
        out.append(
            {
                "label": label,
                "doc": doc,
                "chunks": [chunk.hex() for chunk in chunks],
                "frames": frames,
                "counters": decoder.counters,
            }
        )
    return out


# ------------------------------------------------------------------ CAN frames


def _can_vectors(spec: ProtocolSpec, rng: random.Random) -> list[dict[str, Any]]:
    bits = int(spec.framing["can_node_bits"])
    known = {m.id for m in spec.messages}
    cases: list[tuple[str, list[tuple[int, bool, bool, bytes]]]] = []
    valid = []
    for msg in spec.messages:
        values = {f.name: rng.randint(f.min, f.max) for f in msg.public_fields}
        node = rng.randrange(1 << bits)
        valid.append(((msg.id << bits) | node, False, False, pack_fields(msg, values)))
    cases.append(("valid", valid))
    unknown = [i for i in range(128) if i not in known]
    cases.append(
        (
            "unknown_id",
            [((i << bits) | rng.randrange(1 << bits), False, False, b"\x01") for i in unknown[:6]]
            + [(0x7FF, False, False, b"")],
        )
    )
    bad_length = []
    for msg in spec.messages[:6]:
        can_id = (msg.id << bits) | 1
        bad_length.append((can_id, False, False, bytes(msg.length + 1)))
        bad_length.append((can_id, False, False, bytes(max(0, msg.length - 1))))
    bad_length.append(((spec.messages[0].id << bits) | 2, False, False, bytes(9)))
    cases.append(("bad_length", bad_length))
    first = spec.messages[0]
    data = pack_fields(first, {f.name: f.max for f in first.public_fields})
    cases.append(
        (
            "not_classic",
            [
                ((first.id << bits) | 1, True, False, data),
                ((first.id << bits) | 1, False, True, b""),
                (0x800, False, False, data),
                (0x1FFFFFFF, True, False, data),
            ],
        )
    )
    out_of_range = []
    for msg in spec.messages:
        for _, payload in _out_of_range_payloads(msg):
            out_of_range.append(
                ((msg.id << bits) | rng.randrange(1 << bits), False, False, payload)
            )
    cases.append(("out_of_range", out_of_range))
    mixed = [frame for _, frames in cases for frame in frames]
    rng.shuffle(mixed)
    cases.append(("mixed", mixed))
    out = []
    for label, frames in cases:
        counters = dict.fromkeys(COUNTER_NAMES, 0)
        decoded = [_can_decode(spec, counters, frame) for frame in frames]
        out.append(
            {
                "label": label,
                "frames": [
                    {"can_id": i, "extended": e, "remote": r, "data": d.hex()}
                    for i, e, r, d in frames
                ],
                "decoded": decoded,
                "counters": counters,
            }
        )
    return out


# ------------------------------------------------------------------ rendering


def _document(spec: ProtocolSpec, sections: dict[str, list[dict[str, Any]]]) -> str:
    """One vector per line: small diffs when the spec changes, still valid JSON."""
    lines = [
        "{",
        f'"_generated": {json.dumps(_BANNER)},',
        f'"seed": {SEED},',
        f'"protocol_version": {spec.protocol_version},',
        f'"schema_hash": {spec.schema_hash},',
    ]
    names = list(sections)
    for n, name in enumerate(names):
        items = sections[name]
        lines.append(f'"{name}": [')
        for k, item in enumerate(items):
            comma = "," if k < len(items) - 1 else ""
            lines.append(json.dumps(item, separators=(",", ":")) + comma)
        lines.append("]" + ("," if n < len(names) - 1 else ""))
    lines.append("}")
    return "\n".join(lines) + "\n"


def _rng(salt: str) -> random.Random:
    return random.Random(f"{SEED}:{salt}")


def render_message_vectors(spec: ProtocolSpec) -> str:
    """The full text of ``messages.json``."""
    return _document(
        spec,
        {
            "messages": _message_vectors(spec),
            "encode_errors": _encode_errors(spec),
        },
    )


def render_serial_vectors(spec: ProtocolSpec) -> str:
    """The full text of ``serial_streams.json``."""
    return _document(spec, {"streams": _serial_vectors(spec, _rng("serial"))})


def render_can_vectors(spec: ProtocolSpec) -> str:
    """The full text of ``can_frames.json``."""
    return _document(spec, {"cases": _can_vectors(spec, _rng("can"))})


VECTOR_TARGETS: dict[str, Callable[[ProtocolSpec], str]] = {
    "firmware_proto/wire/vectors/messages.json": render_message_vectors,
    "firmware_proto/wire/vectors/serial_streams.json": render_serial_vectors,
    "firmware_proto/wire/vectors/can_frames.json": render_can_vectors,
}
"""Vector files (relative to the repository root) and their renderers."""

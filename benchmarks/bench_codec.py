"""Codec throughput beside pymavlink and cantools, and recovery from a corrupted stream.

Run: ``.venv/bin/python -m benchmarks.bench_codec [--quick]``

Every figure is the median of several timed repeats in this process, on this machine,
in the same run, so the ratios are comparable even when the absolute numbers are not:

- ours, serial: MOTION and ENCODERS framed (COBS + CRC-16) and decoded by the
  incremental decoder, one frame per ``feed`` call (the worst case) and a 1000-frame
  buffer per call (a busy link);
- ours, CAN: payload + identifier, and the counting CAN decoder;
- pymavlink: MAVLink 2 COMMAND_LONG and MANUAL_CONTROL ``pack`` and ``parse_buffer``;
- cantools: our generated DBC, ``encode_message`` and ``decode_message``.

The target is at least 3x pymavlink's rates.

Then recovery: a stream of 200,000 distinct MOTION frames (20,000 with ``--quick``) in
which 1 % of the frames have one flipped bit, decoded in 4 KiB feeds: the intact frames
recovered (all, the target), altered frames delivered (none, the target) and what the
decoder dropped, by reason and in bytes.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from collections.abc import Callable
from typing import Any

from firmware_proto.wire import codegen
from firmware_proto.wire.canmap import CanDecoder, encode_can
from firmware_proto.wire.framing import FrameDecoder, encode_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Encoders, Motion

Row = tuple[str, str, float]


def rate(fn: Callable[[int], None], n: int, repeats: int) -> float:
    """Median operations per second of ``fn(n)`` (which performs ``n`` operations)."""
    fn(max(1, n // 10))  # warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(n)
        times.append(time.perf_counter() - t0)
    return n / statistics.median(times)


def ours(n: int, repeats: int) -> list[Row]:
    rows: list[Row] = []
    for name, msg in (
        ("MOTION", Motion(513, 1, 45, 23000)),
        ("ENCODERS", Encoders(1234, -567890, 567890)),
    ):
        wire = encode_frame(msg, 7)

        def enc(k: int, msg=msg) -> None:
            for i in range(k):
                encode_frame(msg, i)

        def dec_one(k: int, wire=wire) -> None:
            d = FrameDecoder()
            for _ in range(k):
                d.feed(wire)

        block = wire * 1000

        def dec_stream(k: int, block=block) -> None:
            d = FrameDecoder()
            for _ in range(max(1, k // 1000)):
                d.feed(block)

        arb, data = encode_can(msg, 1)

        def can_enc(k: int, msg=msg) -> None:
            for _ in range(k):
                encode_can(msg, 1)

        def can_dec(k: int, arb=arb, data=data) -> None:
            d = CanDecoder()
            for _ in range(k):
                d.decode(arb, data)

        rows += [
            (f"ours serial {name}", "encode", rate(enc, n, repeats)),
            (f"ours serial {name}", "decode, 1 frame/feed", rate(dec_one, n, repeats)),
            (f"ours serial {name}", "decode, 1000 frames/feed", rate(dec_stream, n, repeats)),
            (f"ours CAN {name}", "encode", rate(can_enc, n, repeats)),
            (f"ours CAN {name}", "decode", rate(can_dec, n, repeats)),
        ]
    return rows


def pymavlink_rows(n: int, repeats: int) -> list[Row]:
    from pymavlink.dialects.v20 import common as mavlink2

    rows: list[Row] = []
    sender = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    makers: dict[str, Callable[[], Any]] = {
        "COMMAND_LONG": lambda: sender.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        "MANUAL_CONTROL": lambda: sender.manual_control_encode(1, 500, -200, 600, 0, 0),
    }
    for name, make in makers.items():
        wire = make().pack(sender)

        def enc(k: int, make=make) -> None:
            for _ in range(k):
                make().pack(sender)

        def dec(k: int, wire=wire) -> None:
            receiver = mavlink2.MAVLink(None, srcSystem=2, srcComponent=1)
            for _ in range(k):
                receiver.parse_buffer(wire)

        rows += [
            (f"pymavlink {name}", "encode (pack)", rate(enc, n, repeats)),
            (f"pymavlink {name}", "decode (parse_buffer)", rate(dec, n, repeats)),
        ]
    return rows


def cantools_rows(n: int, repeats: int) -> list[Row]:
    import cantools

    db = cantools.database.load_file(
        str(codegen.REPO_ROOT / "firmware_proto" / "wire" / "rover.dbc")
    )
    assert isinstance(db, cantools.database.can.Database)
    rows: list[Row] = []
    for name, msg in (
        ("MOTION", Motion(513, 1, 45, 23000)),
        ("ENCODERS", Encoders(1234, -567890, 567890)),
    ):
        signals = msg.to_dict()
        frame = db.get_message_by_name(name)
        data = frame.encode(signals, scaling=False)

        def enc(k: int, frame=frame, signals=signals) -> None:
            for _ in range(k):
                frame.encode(signals, scaling=False)

        def dec(k: int, frame=frame, data=data) -> None:
            for _ in range(k):
                frame.decode(data, scaling=False, decode_choices=False)

        rows += [
            (f"cantools {name}", "encode", rate(enc, n, repeats)),
            (f"cantools {name}", "decode", rate(dec, n, repeats)),
        ]
    return rows


RECOVERY_REASONS = ("crc", "framing", "oversize", "unknown_id", "bad_length", "out_of_range")
"""Drop reasons of :class:`~firmware_proto.wire.counters.RxCounters` a serial stream can show."""


def recovery(frames: int, ratio: float, seed: int) -> dict[str, float]:
    """Decode a stream in which ``ratio`` of the frames have one flipped bit.

    Every sent MOTION is distinct (``seq``, ``speed`` and ``distance`` cycle with
    coprime periods), so a delivered message names the one frame it came from: a message
    that was never sent is an altered frame delivered, and an untouched frame counts as
    recovered only if its own message came out. Everything is linear in ``frames``.

    Returns:
        counts (frames, corrupted, intact, recovered, corrupted_delivered, altered,
        duplicated, delivered), the decoder's drop counters by reason (frames or runs)
        and ``dropped_bytes``, and ``rate`` (delivered frames/s of decoding, 4 KiB feeds).
    """
    rng = random.Random(seed)
    msgs = [Motion(i & 0xFFFF, 1 + i % 4, i % 61, (i * 37) % 30001) for i in range(frames)]
    index: dict[Message, int] = {m: i for i, m in enumerate(msgs)}
    if len(index) != frames:
        raise RuntimeError("recovery stream: sent messages must be distinct")
    wires = [bytearray(encode_frame(m, i)) for i, m in enumerate(msgs)]
    hit: set[int] = set()
    for i, w in enumerate(wires):
        if rng.random() < ratio:
            w[rng.randrange(len(w))] ^= 1 << rng.randrange(8)
            hit.add(i)
    stream = b"".join(bytes(w) for w in wires)
    decoder = FrameDecoder()
    t0 = time.perf_counter()
    got = [
        f.message
        for start in range(0, len(stream), 4096)
        for f in decoder.feed(stream[start : start + 4096])
    ]
    seconds = time.perf_counter() - t0
    sources = [index.get(m) for m in got]
    delivered = {i for i in sources if i is not None}
    counters = decoder.counters
    return {
        "frames": frames,
        "corrupted": len(hit),
        "intact": frames - len(hit),
        "recovered": len(delivered - hit),
        "corrupted_delivered": len(delivered & hit),
        "altered": sources.count(None),
        "duplicated": len(got) - sources.count(None) - len(delivered),
        "delivered": len(got),
        **{reason: getattr(counters, reason) for reason in RECOVERY_REASONS},
        "rejected": counters.rejected,
        "dropped_bytes": counters.dropped_bytes,
        "lost": counters.lost,
        "bytes": counters.bytes,
        "rate": len(got) / seconds,
    }


def recovery_tables(rec: dict[str, float]) -> str:
    """The two Markdown tables of :func:`recovery`: what came out, and what was dropped."""
    outcome = [
        ("frames", "frames"),
        ("corrupted", "corrupted"),
        ("intact", "intact"),
        ("recovered", "intact recovered"),
        ("corrupted_delivered", "corrupted, delivered unaltered"),
        ("altered", "altered delivered"),
        ("duplicated", "duplicated"),
        ("rate", "decode frames/s"),
    ]
    drops = [
        *((reason, reason.replace("_", " ")) for reason in RECOVERY_REASONS),
        ("rejected", "rejected (all reasons)"),
        ("dropped_bytes", "dropped bytes"),
        ("bytes", "bytes fed"),
        ("lost", "lost (frame counter gaps)"),
    ]
    lines = [
        f"Recovery from a stream with {rec['corrupted'] / rec['frames']:.0%} corrupted frames "
        "(one flipped bit each; 4 KiB feeds)",
        "",
    ]
    for title, columns in (("", outcome), ("Dropped by the decoder, by reason", drops)):
        if title:
            lines += ["", title, ""]
        lines.append("| " + " | ".join(head for _, head in columns) + " |")
        lines.append("|" + "---:|" * len(columns))
        lines.append("| " + " | ".join(f"{rec[key]:,.0f}" for key, _ in columns) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="fewer iterations (smoke run)")
    args = parser.parse_args(argv)
    n, repeats = (5_000, 3) if args.quick else (100_000, 7)

    rows = ours(n, repeats) + pymavlink_rows(n // 4, repeats) + cantools_rows(n // 4, repeats)
    print(f"Codec throughput (median of {repeats} repeats; frames/s; higher is better)\n")
    print("| codec | operation | frames/s |")
    print("|---|---|---:|")
    for codec, op, value in rows:
        print(f"| {codec} | {op} | {value:,.0f} |")

    by = {(c, o): v for c, o, v in rows}
    mav_dec = max(
        by[("pymavlink COMMAND_LONG", "decode (parse_buffer)")],
        by[("pymavlink MANUAL_CONTROL", "decode (parse_buffer)")],
    )
    mav_enc = max(
        by[("pymavlink COMMAND_LONG", "encode (pack)")],
        by[("pymavlink MANUAL_CONTROL", "encode (pack)")],
    )
    our_enc = min(v for (c, o), v in by.items() if c.startswith("ours") and o == "encode")
    our_dec = min(v for (c, o), v in by.items() if c.startswith("ours") and o.startswith("decode"))
    print("\nRatio against pymavlink's faster message (target >= 3x):")
    for what, our, peer in (("encode", our_enc, mav_enc), ("decode", our_dec, mav_dec)):
        ratio = our / peer
        print(f"- {what}: our slowest {our:,.0f} / pymavlink's fastest {peer:,.0f} = {ratio:.1f}x")

    rec = recovery(20_000 if args.quick else 200_000, 0.01, seed=1)
    print("\n" + recovery_tables(rec))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Codec round trip over a real pty: pyserial writes frames, the decoder reads them back.

A smoke test of the serial path without a controller model: frames survive a real tty,
corrupted ones are dropped and counted, and every intact frame after one is recovered.
"""

from __future__ import annotations

import os
import random
import select
import threading
import time
from dataclasses import dataclass, field

import serial

from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.wire.framing import FrameDecoder, encode_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Encoders, Heartbeat, Imu, Motion, PoseMsg, Stop

__all__ = ["RoundtripResult", "pty_roundtrip", "sample_messages"]


def sample_messages(count: int, rng: random.Random) -> list[Message]:
    """A reproducible mix of host and controller messages with random valid values."""
    out: list[Message] = []
    for i in range(count):
        kind = i % 6
        if kind == 0:
            out.append(
                Motion(i & 0xFFFF, rng.randint(0, 4), rng.randint(0, 60), rng.randint(0, 30000))
            )
        elif kind == 1:
            out.append(
                Encoders(
                    i & 0xFFFF,
                    rng.randint(-(1 << 23), (1 << 23) - 1),
                    rng.randint(-(1 << 23), (1 << 23) - 1),
                )
            )
        elif kind == 2:
            out.append(Imu(i & 0xFFFF, rng.randint(-3000, 3000), rng.randint(-900, 900), 0))
        elif kind == 3:
            out.append(
                PoseMsg(
                    rng.randint(-50000, 50000),
                    rng.randint(-50000, 50000),
                    rng.randint(-1800, 1800),
                    rng.randint(0, 15),
                    rng.randint(0, 255),
                )
            )
        elif kind == 4:
            out.append(Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 0x1234, 0, 0))
        else:
            out.append(Stop(1 + (i & 0x7FFF), 0))
    return out


@dataclass
class RoundtripResult:
    """What a round trip sent, what came back, and how fast."""

    sent: int
    corrupted: int
    received: int
    intact_expected: int
    intact_received: int
    altered: int
    seconds: float
    wire_bytes: int
    device: str
    counters: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Every intact frame came back unaltered, and nothing else did."""
        return self.intact_received == self.intact_expected and self.altered == 0

    def report(self) -> str:
        """Human-readable summary."""
        dropped = {k: v for k, v in self.counters.items() if v and k not in ("frames", "bytes")}
        return "\n".join(
            [
                f"pty round trip over {self.device} with pyserial",
                f"  sent {self.sent} frames ({self.wire_bytes} bytes), "
                f"{self.corrupted} corrupted on purpose",
                f"  received {self.received} valid frames in {self.seconds * 1e3:.1f} ms "
                f"({self.received / max(self.seconds, 1e-9):,.0f} frames/s)",
                f"  intact frames recovered: {self.intact_received}/{self.intact_expected}; "
                f"altered frames delivered: {self.altered}",
                f"  decoder dropped: {dropped or 'nothing'}",
                f"  result: {'OK' if self.ok else 'FAILED'}",
            ]
        )


def pty_roundtrip(
    count: int = 20000, seed: int = 1, corrupt_ratio: float = 0.01, timeout_s: float = 30.0
) -> RoundtripResult:
    """Write ``count`` frames into a pty through pyserial, decode them from the other end;
    ``corrupt_ratio`` of them get one random bit flipped (chosen by ``seed``, as the
    values are); the reader is given up after ``timeout_s``.
    """
    rng = random.Random(seed)
    messages = sample_messages(count, rng)
    frames = [encode_frame(m, i) for i, m in enumerate(messages)]
    corrupted: set[int] = set()
    for i in range(count):
        if rng.random() < corrupt_ratio:
            raw = bytearray(frames[i])
            pos = rng.randrange(len(raw))
            raw[pos] ^= 1 << rng.randrange(8)
            frames[i] = bytes(raw)
            corrupted.add(i)
    stream = b"".join(frames)
    decoder = FrameDecoder()
    received: list[tuple[int, Message]] = []
    with (
        PtyPair() as pair,
        serial.Serial(pair.device, timeout=1.0, write_timeout=timeout_s) as port,
    ):

        def write() -> None:
            for start in range(0, len(stream), 4096):
                port.write(stream[start : start + 4096])
            port.flush()

        writer = threading.Thread(target=write, name="roundtrip-writer", daemon=True)
        t0 = time.perf_counter()
        writer.start()
        deadline = time.monotonic() + timeout_s
        while decoder.counters.bytes < len(stream) and time.monotonic() < deadline:
            ready, _, _ = select.select([pair.master_fd], [], [], 0.2)
            if ready:
                received += [
                    (f.seq, f.message) for f in decoder.feed(os.read(pair.master_fd, 65536))
                ]
        seconds = time.perf_counter() - t0
        writer.join(timeout_s)
    # Match each delivered frame to the next sent one with the same counter and content.
    sent = [(i & 0xFF, m) for i, m in enumerate(messages)]
    j = intact = altered = 0
    for seq, msg in received:
        k = j
        while k < count and sent[k] != (seq, msg):
            k += 1
        if k == count:
            altered += 1
            continue
        intact += k not in corrupted
        j = k + 1
    return RoundtripResult(
        sent=count,
        corrupted=len(corrupted),
        received=len(received),
        intact_expected=count - len(corrupted),
        intact_received=intact,
        altered=altered,
        seconds=seconds,
        wire_bytes=len(stream),
        device=pair.device,
        counters=decoder.counters.as_dict(),
    )

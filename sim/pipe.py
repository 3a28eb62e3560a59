"""One direction of a simulated medium: the serial line's bytes or the CAN bus's frames,
in virtual time, with the faults of a scenario applied as each frame is sent.

A :class:`Pipe` takes one encoded frame at a time (:meth:`Pipe.send`) with its send time
and delivers it, or what survives of it, at its arrival time, first in first out
(:meth:`Pipe.due`, :meth:`Pipe.pop`). What it models:

- **serial** (115200 baud, 8N1: 86.8 us a byte): frames are serialised one after the
  other (a frame waits for the line), a cut removes the bytes sent during it (a frame
  cut in the middle arrives as a head or a tail that the decoder must resynchronise
  on), corruption flips one bit of one byte, a drop loses the whole frame;
- **CAN** (500 kbit/s, about 0.25 ms a frame): a frame arrives whole or not at all (the
  bus's own CRC turns corruption into a drop), and may arrive twice (a CAN receiver can
  take a frame whose acknowledgement the sender missed, and the sender sends it again);
- both: extra delay (order kept: a frame never overtakes an earlier one) and the loss
  of frames of chosen kinds (an ACK, a STATUS, an IDENT...).

Pure and seeded: the random draws come from the ``random.Random`` given.
"""

from __future__ import annotations

import random
from collections import deque
from dataclasses import dataclass, field

from firmware_proto.wire.message import Message

__all__ = ["BYTE_S", "CAN_FRAME_S", "Delivery", "Pipe", "Window"]

BYTE_S = 10.0 / 115200.0
"""One byte on a 115200 baud 8N1 line, s."""
CAN_FRAME_S = 0.00025
"""One classic CAN frame with 8 data bytes at 500 kbit/s, about, s."""
LATENCY_S = 0.0002
"""Driver and adapter latency added to every frame, s."""


@dataclass(frozen=True)
class Window:
    """A fault in force on this pipe from ``start_s`` until ``end_s`` (virtual time).

    Attributes:
        kind: ``cut``, ``drop``, ``corrupt``, ``delay``, ``kind-loss`` or ``dup``.
        level: a probability (``drop``, ``corrupt``, ``kind-loss``, ``dup``) or the
            extra delay in seconds (``delay``); unused by ``cut``.
        kinds: the message names a ``kind-loss`` window loses.
    """

    kind: str
    start_s: float
    end_s: float
    level: float = 1.0
    kinds: tuple[str, ...] = ()


@dataclass
class Delivery:
    """What arrives: the bytes of one serial frame (all of them or a piece) or one CAN
    frame, the message it was sent as and when it was sent.

    Attributes:
        at_s: arrival time.
        data: the bytes (serial) or the CAN data field.
        can_id: the CAN identifier (``None`` on serial).
        msg: the message as sent (before any damage).
        sent_s: when the sender handed it to the medium.
        intact: nothing of it was cut or corrupted.
        meta: what the sender attached (the simulator's ground truth about the frame).
    """

    at_s: float
    data: bytes
    can_id: int | None
    msg: Message
    sent_s: float
    intact: bool = True
    meta: object = None


@dataclass
class Pipe:
    """One direction of a medium (see the module docstring).

    Attributes:
        medium: ``serial`` or ``can``.
        rng: the seeded generator of this pipe's faults.
        windows: the faults of the scenario on this direction.
    """

    medium: str
    rng: random.Random
    windows: tuple[Window, ...] = ()
    _queue: deque[Delivery] = field(default_factory=deque)  # never replaced: Rig.run reads it
    _free_at: float = 0.0
    _last_at: float = 0.0
    sent: int = 0
    """Frames handed to the pipe."""
    lost: int = 0
    """Frames that arrived damaged or not at all (each duplicate arrival not counted)."""
    duplicated: int = 0

    def due(self) -> float:
        """Arrival time of the next delivery (infinity when none waits)."""
        return self._queue[0].at_s if self._queue else float("inf")

    def pop(self) -> Delivery:
        """The next delivery, in arrival order."""
        return self._queue.popleft()

    def clear(self) -> None:
        """Forget everything in flight (a device unplugged: its buffers are gone)."""
        self._queue.clear()

    def send_batch(self, now: float, frames: list[tuple[bytes, Message]]) -> list[bool]:
        """Hand several encoded serial frames to the medium at ``now``, in order (what
        one control tick sends); whether each will arrive whole. While no fault can touch
        them they travel as one delivery: the decoder splits them as it would."""
        if self.medium != "serial" or len(frames) == 1:
            return [self.send(now, data, msg) for data, msg in frames]
        start = max(now, self._free_at)
        data = b"".join(d for d, _ in frames)
        end = start + len(data) * BYTE_S
        if any(w.start_s < end and w.end_s > start for w in self.windows):
            return [self.send(now, d, msg) for d, msg in frames]
        self.sent += len(frames)
        self._free_at = end
        at = max(end + LATENCY_S, self._last_at)
        self._last_at = at
        self._queue.append(Delivery(at, data, None, frames[0][1], now))
        return [True] * len(frames)

    def _active(self, t: float) -> list[Window]:
        return [w for w in self.windows if w.start_s <= t < w.end_s]

    def send(
        self,
        now: float,
        data: bytes,
        msg: Message,
        *,
        can_id: int | None = None,
        meta: object = None,
    ) -> bool:
        """Hand one encoded frame to the medium at ``now``; whether it will arrive whole."""
        self.sent += 1
        serial = self.medium == "serial"
        start = max(now, self._free_at) if serial else now
        end = start + (len(data) * BYTE_S if serial else CAN_FRAME_S)
        if serial:
            self._free_at = end
        active = self._active(start) if self.windows else []
        delay = LATENCY_S
        intact = True
        copies = 1
        for w in active:
            kind = w.kind
            if kind == "delay":
                delay += w.level
            elif kind == "drop" or (kind == "corrupt" and not serial):
                if self.rng.random() < w.level:
                    self.lost += 1
                    return False
            elif kind == "kind-loss":
                if msg.NAME in w.kinds and self.rng.random() < w.level:
                    self.lost += 1
                    return False
            elif kind == "corrupt":
                if self.rng.random() < w.level:
                    data = _flip(data, self.rng)
                    intact = False
            elif kind == "dup" and not serial and self.rng.random() < w.level:
                copies = 2
        for w in self.windows:
            if w.kind != "cut" or w.end_s <= start or w.start_s >= end:
                continue
            if not serial:
                self.lost += 1
                return False
            data, intact = _cut(data, start, w), False
            if not data:
                self.lost += 1
                return False
        if not intact:
            self.lost += 1
        at = max(end + delay, self._last_at)
        self._last_at = at
        for _ in range(copies):
            self._queue.append(Delivery(at, data, can_id, msg, now, intact, meta))
        if copies > 1:
            self.duplicated += 1
        return intact


def _flip(data: bytes, rng: random.Random) -> bytes:
    i = rng.randrange(len(data))
    out = bytearray(data)
    out[i] ^= 1 << rng.randrange(8)
    return bytes(out)


def _cut(data: bytes, start: float, w: Window) -> bytes:
    """The bytes of a frame sent from ``start`` that lie outside cut ``w``."""
    n = len(data)
    first = max(0, min(n, int((w.start_s - start) / BYTE_S)))  # bytes before the cut
    resume = max(0, min(n, -int(-(w.end_s - start) // BYTE_S)))  # first byte after it
    return data[:first] + data[resume:]

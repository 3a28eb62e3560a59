"""Receive counters shared by the serial and CAN decoders."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["RxCounters"]


@dataclass
class RxCounters:
    """What a decoder received and what it dropped, by reason. Counts only grow.

    Attributes:
        frames: valid frames delivered.
        bytes, dropped_bytes: bytes fed, and discarded in rejected frames or garbage.
        framing: COBS structure broken, or too short to be a frame.
        oversize: more bytes between delimiters than any frame has.
        crc: CRC mismatch.
        unknown_id: message id not in the protocol.
        bad_length: payload length differs from the message's.
        out_of_range: a field value outside its wire range.
        lost: gaps in the sender's frame counter.
        not_classic: extended-id or remote CAN frames. (This one is CAN only; ``bytes``
            to ``crc`` and ``lost`` are serial only.)
    """

    frames: int = 0
    bytes: int = 0
    dropped_bytes: int = 0
    framing: int = 0
    oversize: int = 0
    crc: int = 0
    unknown_id: int = 0
    bad_length: int = 0
    out_of_range: int = 0
    lost: int = 0
    not_classic: int = 0

    @property
    def rejected(self) -> int:
        """Frames (or garbage runs) dropped for any reason."""
        return (
            self.framing
            + self.oversize
            + self.crc
            + self.unknown_id
            + self.bad_length
            + self.out_of_range
            + self.not_classic
        )

    def as_dict(self) -> dict[str, int]:
        """Counter values by name."""
        return asdict(self)

"""Consistent Overhead Byte Stuffing (COBS), the zero-free encoding of serial frames.

:func:`encode` turns any bytes into bytes without ``0x00`` (one byte of overhead per 254
input bytes), so ``0x00`` can delimit frames; :func:`decode` reverses it and returns
``None``, never raising, for input that no encoder could have produced. Pure functions,
no state; see Cheshire and Baker, "Consistent Overhead Byte Stuffing", IEEE/ACM ToN 1999.
"""

from __future__ import annotations

__all__ = ["decode", "encode", "max_encoded_length"]


def max_encoded_length(n: int) -> int:
    """Largest COBS output for ``n`` input bytes (without delimiters)."""
    return n + n // 254 + 1


def encode(data: bytes) -> bytes:
    """COBS-encode ``data``; the result contains no zero byte."""
    if len(data) < 254:
        # Fast path for protocol frames: each zero-free run becomes (length + 1) + run.
        return b"".join([bytes((len(run) + 1,)) + run for run in data.split(b"\x00")])
    out = bytearray()
    for run in data.split(b"\x00"):
        rest = run
        while len(rest) >= 254:
            out.append(0xFF)
            out += rest[:254]
            rest = rest[254:]
        out.append(len(rest) + 1)
        out += rest
    return bytes(out)


def decode(data: bytes) -> bytes | None:
    """Decode one COBS block (no delimiters); ``None`` if it is not valid COBS."""
    n = len(data)
    if n < 255:
        # Short blocks (every protocol frame) cannot hold a 0xFF run: each code is
        # followed by (code - 1) data bytes and, unless it ends the block, a zero.
        pieces = []
        i = 0
        while i < n:
            code = data[i]
            end = i + code
            if code == 0 or end > n:
                return None
            pieces.append(data[i + 1 : end])
            i = end
        return b"\x00".join(pieces)
    out = bytearray()
    i = 0
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            return None
        out += data[i + 1 : end]
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)

"""Reading a request body safely: media type, framing, size limit, strict JSON.

Pure functions over a header mapping and a binary reader, so they can be tested without
a socket. The limits hold *before* reading: a declared ``Content-Length`` over the limit
is refused without reading a byte; a chunked body is refused as soon as its running size
passes the limit. A body with neither framing is refused (411) rather than read to EOF.
"""

from __future__ import annotations

import json
import re
from typing import Any, Protocol

from gate.errors import (
    BadRequestError,
    LengthRequiredError,
    PayloadTooLargeError,
    UnsupportedMediaError,
)

__all__ = [
    "JSON_MEDIA_TYPE",
    "BodyFraming",
    "body_framing",
    "check_json_media_type",
    "parse_json",
    "read_body",
]

JSON_MEDIA_TYPE = "application/json"

_DIGITS = re.compile(r"[0-9]{1,19}")
_HEX = re.compile(r"[0-9A-Fa-f]{1,16}")
_MAX_LINE = 1024
_MAX_TRAILERS = 32


class _Reader(Protocol):
    def read(self, size: int, /) -> bytes: ...

    def readline(self, size: int, /) -> bytes: ...


class _Headers(Protocol):
    def get(self, name: str, default: None = None) -> str | None: ...

    def get_all(self, name: str, failobj: None = None) -> list[str] | None: ...


class BodyFraming:
    """How a request says its body ends: ``length`` bytes, chunked, or no body."""

    def __init__(self, *, length: int | None = None, chunked: bool = False) -> None:
        self.length = length
        self.chunked = chunked

    @property
    def has_body(self) -> bool:
        """Whether any body bytes follow the headers."""
        return self.chunked or bool(self.length)

    def __repr__(self) -> str:
        return f"BodyFraming(length={self.length}, chunked={self.chunked})"


def body_framing(headers: _Headers) -> BodyFraming:
    """The body framing the headers declare (RFC 9112 section 6).

    Raises:
        BadRequestError: both ``Transfer-Encoding`` and ``Content-Length``, a transfer
            coding other than ``chunked``, or a malformed or conflicting length.
    """
    codings = headers.get_all("Transfer-Encoding") or []
    lengths = headers.get_all("Content-Length") or []
    if codings:
        if lengths:
            raise BadRequestError(
                "both Transfer-Encoding and Content-Length given", code="bad_framing"
            )
        names = [c.strip().lower() for value in codings for c in value.split(",")]
        if names != ["chunked"]:
            raise BadRequestError(
                f"unsupported Transfer-Encoding {', '.join(names)!r} (only chunked)",
                code="bad_framing",
            )
        return BodyFraming(chunked=True)
    if not lengths:
        return BodyFraming()
    values = {v.strip() for value in lengths for v in value.split(",")}
    if len(values) != 1 or not _DIGITS.fullmatch(next(iter(values))):
        raise BadRequestError(f"invalid Content-Length {lengths!r}", code="bad_framing")
    return BodyFraming(length=int(next(iter(values))))


def check_json_media_type(content_type: str | None) -> None:
    """Accept ``application/json``, optionally with ``charset=utf-8``.

    Raises:
        UnsupportedMediaError: missing, another media type, or another charset.
    """
    if content_type is None:
        raise UnsupportedMediaError(f"Content-Type missing; send {JSON_MEDIA_TYPE}")
    media, *params = (p.strip() for p in content_type.split(";"))
    if media.lower() != JSON_MEDIA_TYPE:
        raise UnsupportedMediaError(f"Content-Type {media!r} not supported; send {JSON_MEDIA_TYPE}")
    for param in params:
        key, _, value = param.partition("=")
        if key.strip().lower() == "charset" and value.strip().strip('"').lower() not in (
            "utf-8",
            "utf8",
        ):
            raise UnsupportedMediaError(f"charset {value.strip()!r} not supported; send UTF-8")


def read_body(framing: BodyFraming, stream: _Reader, limit: int) -> bytes:
    """Read the body ``framing`` declares from ``stream``, at most ``limit`` bytes.

    Raises:
        LengthRequiredError: no framing (a POST must say how long its body is).
        PayloadTooLargeError: the declared or running size passes ``limit`` (checked
            before reading any of it for a declared length).
        BadRequestError: the stream ends early, or the chunked framing is malformed.
    """
    if framing.chunked:
        return _read_chunked(stream, limit)
    if framing.length is None:
        raise LengthRequiredError("a body needs Content-Length (or chunked Transfer-Encoding)")
    if framing.length > limit:
        raise PayloadTooLargeError(
            f"body of {framing.length} bytes is over the limit of {limit} bytes"
        )
    data = stream.read(framing.length) if framing.length else b""
    if len(data) != framing.length:
        raise BadRequestError(
            f"body ended after {len(data)} of {framing.length} bytes", code="truncated_body"
        )
    return data


def _line(stream: _Reader) -> bytes:
    line = stream.readline(_MAX_LINE + 1)
    if len(line) > _MAX_LINE or not line.endswith(b"\r\n"):
        raise BadRequestError("malformed chunked body", code="bad_framing")
    return line[:-2]


def _read_chunked(stream: _Reader, limit: int) -> bytes:
    parts: list[bytes] = []
    total = 0
    while True:
        size_text = _line(stream).split(b";", 1)[0].strip().decode("ascii", "replace")
        if not _HEX.fullmatch(size_text):
            raise BadRequestError(f"bad chunk size {size_text!r}", code="bad_framing")
        size = int(size_text, 16)
        if size == 0:
            break
        total += size
        if total > limit:
            raise PayloadTooLargeError(f"chunked body is over the limit of {limit} bytes")
        chunk = stream.read(size)
        if len(chunk) != size or stream.read(2) != b"\r\n":
            raise BadRequestError("chunked body ended early", code="truncated_body")
        parts.append(chunk)
    for _ in range(_MAX_TRAILERS):
        if not _line(stream):
            return b"".join(parts)
    raise BadRequestError("too many trailer lines", code="bad_framing")


def _no_constants(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def parse_json(body: bytes) -> Any:
    """Parse a body as strict JSON: UTF-8 without BOM, no NaN or Infinity, no duplicate
    keys.

    Raises:
        BadRequestError: code ``not_json``, saying where parsing failed.
    """
    try:
        text = body.decode("utf-8")
        return json.loads(text, parse_constant=_no_constants, object_pairs_hook=_unique_keys)
    except UnicodeDecodeError as exc:
        raise BadRequestError(f"body is not UTF-8: {exc}", code="not_json") from exc
    except ValueError as exc:
        raise BadRequestError(f"body is not JSON: {exc}", code="not_json") from exc

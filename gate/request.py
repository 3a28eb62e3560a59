"""Reading a request: its declared body length, media type and strict JSON.

h11 (under uvicorn, :mod:`firmware_proto.http`) has already checked the framing; what is
left is the gate's own policy: a ``POST`` must declare its body's length (411, rather
than an empty plan), a length over the limit is refused (413) before any of it is read
or ``100 Continue`` sent, and the body must be strict ``application/json`` (415, 400).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from firmware_proto.model.schemacheck import MAX_DEPTH, json_depth
from gate.errors import (
    BadRequestError,
    LengthRequiredError,
    PayloadTooLargeError,
    UnsupportedMediaError,
)

__all__ = [
    "JSON_MEDIA_TYPE",
    "check_declared_length",
    "check_json_media_type",
    "parse_json",
]

JSON_MEDIA_TYPE = "application/json"


def check_declared_length(headers: Mapping[str, str], limit: int) -> int | None:
    """The body length the headers declare (``None`` for chunked).

    Raises:
        LengthRequiredError: neither ``Content-Length`` nor chunked framing.
        PayloadTooLargeError: a declared length over ``limit``.
    """
    if "transfer-encoding" in headers:
        return None  # chunked (h11 accepts no other coding): counted while reading
    text = headers.get("content-length")
    if text is None:
        raise LengthRequiredError("a body needs Content-Length (or chunked Transfer-Encoding)")
    length = int(text)  # h11 has checked it is one decimal number
    if length > limit:
        raise PayloadTooLargeError(f"body of {length} bytes is over the limit of {limit} bytes")
    return length


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
    keys, at most :data:`~firmware_proto.model.schemacheck.MAX_DEPTH` levels deep.

    Raises:
        BadRequestError: code ``not_json``, saying where parsing failed.
    """
    try:
        text = body.decode("utf-8")
        doc = json.loads(text, parse_constant=_no_constants, object_pairs_hook=_unique_keys)
    except UnicodeDecodeError as exc:
        raise BadRequestError(f"body is not UTF-8: {exc}", code="not_json") from exc
    except ValueError as exc:
        raise BadRequestError(f"body is not JSON: {exc}", code="not_json") from exc
    except RecursionError as exc:  # deeper than the parser's stack allows
        raise BadRequestError(
            f"body is nested deeper than {MAX_DEPTH} levels", code="not_json"
        ) from exc
    if json_depth(doc, MAX_DEPTH + 1) > MAX_DEPTH:
        raise BadRequestError(f"body is nested deeper than {MAX_DEPTH} levels", code="not_json")
    return doc

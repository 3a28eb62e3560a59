"""Who may reach an HTTP server of this project: the bind, token and host policy that the
gate and the live view share (docs/gate.md, "Binding and the token").

A non-loopback bind needs a strong token (:func:`check_bind`); with a token every
request must present it, compared in constant time; every request's ``Host`` must name
this server (:class:`HostPolicy`), against DNS rebinding. Pure functions over strings:
the lowest place both the gate and the planner's live view may import.
"""

from __future__ import annotations

import functools
import hmac
import ipaddress
import re
from collections.abc import Iterable
from dataclasses import dataclass

from firmware_proto.errors import BindPolicyError

__all__ = [
    "MIN_TOKEN_CHARS",
    "MIN_TOKEN_DISTINCT",
    "HostPolicy",
    "bearer_token",
    "check_bind",
    "check_token",
    "host_name",
    "is_loopback",
    "is_wildcard",
    "token_matches",
]

MIN_TOKEN_CHARS = 16
"""Shortest token accepted for a non-loopback address, chars (16 URL-safe chars carry 96 bits)."""
MIN_TOKEN_DISTINCT = 8
"""Fewest different characters in such a token (refuses ``aaaaaaaaaaaaaaaa``)."""
_TOKEN_ADVICE = "python3 -c 'import secrets; print(secrets.token_urlsafe(24))'"


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (``127.0.0.0/8``, ``::1``, ``localhost``); other
    host names count as not loopback (they could resolve to anything)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    """Whether ``host`` binds every interface (``0.0.0.0``, ``::``, ``""``)."""
    if host == "":
        return True
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def check_token(token: str | None, *, what: str = "token", strong: bool = False) -> None:
    """Refuse a malformed token (``None``, no token, passes); with ``strong``, a weak one
    too.

    Raises:
        BindPolicyError: ``token`` is empty or has characters that cannot go in a header;
            with ``strong``, it has fewer than :data:`MIN_TOKEN_CHARS` characters or fewer
            than :data:`MIN_TOKEN_DISTINCT` different ones.
    """
    if token is None:
        return
    if not token or not token.isprintable() or token != token.strip():
        raise BindPolicyError(f"{what} must be a non-empty printable string")
    if strong and (len(token) < MIN_TOKEN_CHARS or len(set(token)) < MIN_TOKEN_DISTINCT):
        raise BindPolicyError(
            f"{what} is too weak for a non-loopback address: at least {MIN_TOKEN_CHARS} "
            f"characters, {MIN_TOKEN_DISTINCT} of them different (make one with "
            f"{_TOKEN_ADVICE})"
        )


def check_bind(host: str, token: str | None, *, what: str = "token", hint: str = "") -> None:
    """The bind policy: a non-loopback ``host`` needs a strong token. ``what`` names the
    token in messages (``"view token"``), ``hint`` says how to give one
    (``"--token-file (or ROVER_GATE_TOKEN)"``).

    Raises:
        BindPolicyError: a malformed token, a non-loopback address without one, or with a
            weak one (:func:`check_token`).
    """
    loopback = is_loopback(host)
    check_token(token, what=what, strong=not loopback)
    if token is None and not loopback:
        give = f"give {hint}, or " if hint else ""
        raise BindPolicyError(
            f"refusing to listen on {host!r} without a token: {give}bind a loopback address"
        )


def bearer_token(header: str | None) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header value; ``None`` when the
    header is missing or names another scheme (the scheme is case-insensitive)."""
    if not header:
        return None
    scheme, _, value = header.strip().partition(" ")
    if scheme.lower() != "bearer":
        return None
    return value.strip()


def token_matches(given: str | None, token: str) -> bool:
    """Whether ``given`` is ``token``, compared in constant time (``None`` never is)."""
    if given is None:
        return False
    return hmac.compare_digest(given.encode("utf-8", "surrogateescape"), token.encode())


_NAME = re.compile(r"[a-z0-9._-]+")


@functools.lru_cache(maxsize=256)
def host_name(header: str | None) -> str | None:
    """The name or address of a ``Host`` header value, lower case, without the port,
    the brackets of an IPv6 literal or a trailing dot; ``None`` when it is missing or
    malformed."""
    if not header:
        return None
    text = header.strip().lower()
    if text.startswith("["):
        literal, sep, rest = text[1:].partition("]")
        if not sep or (rest and not (rest.startswith(":") and rest[1:].isdigit())):
            return None
        return literal if _is_ip(literal) else None
    name, _, port = text.partition(":")
    if port and not (port.isascii() and port.isdigit()):
        return None
    name = name.rstrip(".")
    if not name or not _NAME.fullmatch(name):
        return None
    return name


def _is_ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class HostPolicy:
    """Which ``Host`` values name this server.

    Attributes:
        names: names and address literals accepted (lower case, no port).
        any_address: any IP address literal is accepted too (a wildcard bind: a DNS
            rebinding always sends a name, never an address).
    """

    names: frozenset[str]
    any_address: bool = False

    @classmethod
    def for_bind(cls, host: str, extra: Iterable[str] = ()) -> HostPolicy:
        """The names a server bound to ``host`` answers to: a loopback bind, every
        loopback address and ``localhost``; a wildcard bind, any address literal;
        another address, that one; plus ``extra`` (configured names, and for a wildcard
        bind the machine's own name, which the caller looks up)."""
        names = {n.strip().lower().rstrip(".") for n in extra if n.strip()}
        if is_loopback(host):
            return cls(frozenset(names | {"localhost", "127.0.0.1", "::1", host.lower()}))
        if is_wildcard(host):
            return cls(frozenset(names), any_address=True)
        return cls(frozenset(names | {host.lower()}))

    def allows(self, header: str | None) -> bool:
        """Whether a request's ``Host`` header names this server (the answers to the
        headers seen last are kept: a server sees few different ones)."""
        return _allows(self, header)

    def decide(self, header: str | None) -> bool:
        """:meth:`allows`, worked out."""
        name = host_name(header)
        if name is None:
            return False
        if name in self.names:
            return True
        if _is_ip(name):
            return self.any_address or (
                "127.0.0.1" in self.names and ipaddress.ip_address(name).is_loopback
            )
        return False


@functools.lru_cache(maxsize=256)
def _allows(policy: HostPolicy, header: str | None) -> bool:
    return policy.decide(header)

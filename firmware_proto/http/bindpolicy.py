"""Who may reach an HTTP server of this project: the bind and token policy that the
simulation gate and the live view share (docs/gate.md, "Binding and the token").

- A server binds a loopback address unless told otherwise; a non-loopback address needs
  a token (:func:`check_bind`), so that nothing on the network can drive the rover or
  read its state by accident.
- With a token, every request must present it (``Authorization: Bearer <token>``,
  :func:`bearer_token`); it is compared in constant time (:func:`token_matches`).

Pure functions over strings, no I/O: the lowest place both the gate and the planner's
live view may import (the planner may not import the gate).
"""

from __future__ import annotations

import hmac
import ipaddress

from firmware_proto.errors import BindPolicyError

__all__ = ["bearer_token", "check_bind", "check_token", "is_loopback", "token_matches"]


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (``127.0.0.0/8``, ``::1``, ``localhost``).

    Host names other than ``localhost`` count as not loopback (they could resolve to
    anything).
    """
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_token(token: str | None, *, what: str = "token") -> None:
    """Refuse a malformed token (``None`` means no token and passes).

    Raises:
        BindPolicyError: ``token`` is empty or has characters that cannot go in a header.
    """
    if token is not None and (not token or not token.isprintable()):
        raise BindPolicyError(f"{what} must be a non-empty printable string")


def check_bind(host: str, token: str | None, *, what: str = "token", hint: str = "") -> None:
    """The bind policy: a non-loopback ``host`` needs a token.

    Args:
        host: the address to listen on.
        token: the bearer token, or ``None``.
        what: the token's name in messages (``"token"``, ``"view token"``).
        hint: how to give one, for the message (``"--token (or ROVER_GATE_TOKEN)"``).

    Raises:
        BindPolicyError: a malformed token, or a non-loopback address without one.
    """
    check_token(token, what=what)
    if token is None and not is_loopback(host):
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

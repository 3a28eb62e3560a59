"""Who the stack's console answers (:mod:`planner.stack.console_server`): the checks a
request passes before anything is read or done, a pure function of its method and
headers (no I/O, no clock). Only the operator's commands, never a web page or another
user (docs/commands.md, "The stack's console"). In order:

1. ``Host`` names the console as its URL does (loopback: ``127.0.0.1``, ``localhost``
   or ``[::1]``; a wildcard bind: any address literal; with the port), else 421 (DNS
   rebinding sends a name).
2. No ``Origin``, no ``Sec-Fetch-Site`` other than ``none``, else 403 (a browser's).
3. The stack's bearer token, always, else 401.
4. A ``POST`` carries ``X-Rover-Console: 1`` or a JSON content type, else 403 (neither
   passes another origin without a CORS preflight, never granted).
"""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from dataclasses import dataclass, field

from firmware_proto.http.bindpolicy import bearer_token, is_loopback, token_matches
from planner.ground.console_client import CONSOLE_HEADER

__all__ = ["CONSOLE_HEADER", "ConsoleAccess", "Refusal"]

_JSON = "application/json"


@dataclass(frozen=True)
class Refusal:
    """Why a request is refused: its HTTP ``status``, a short ``code`` and one sentence
    for the operator (``message``)."""

    status: int
    code: str
    message: str


def _literal(host: str) -> str:
    """``host`` as it appears in a URL's authority (an IPv6 address in brackets)."""
    return f"[{host}]" if ":" in host else host


def _is_ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text.strip("[]"))
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class ConsoleAccess:
    """The checks above, for one console.

    Attributes:
        hosts: the ``Host`` values accepted, lower case, each with its port.
        port: the console's TCP port.
        any_address: any IP address literal with :attr:`port` is accepted too (a
            wildcard bind; a DNS rebinding always sends a name).
        token: the bearer token every request must present.
    """

    hosts: frozenset[str]
    port: int
    token: str = field(repr=False)
    any_address: bool = False

    @classmethod
    def for_bind(cls, host: str, port: int, token: str) -> ConsoleAccess:
        """The access of a console bound to ``host:port`` (the port actually bound)."""
        names = {host.lower()}
        if is_loopback(host):
            names.add("localhost")
        wildcard = host in ("", "0.0.0.0", "::")
        hosts = frozenset(f"{_literal(name)}:{port}" for name in names if name)
        return cls(hosts, port, token, any_address=wildcard)

    def _host_ok(self, header: str | None) -> bool:
        if header is None:
            return False
        value = header.strip().lower()
        if value in self.hosts:
            return True
        if not self.any_address:
            return False
        name, sep, port = value.rpartition(":")
        return bool(sep) and port == str(self.port) and _is_ip(name)

    def refusal(self, method: str, headers: Mapping[str, str]) -> Refusal | None:
        """Why the request is refused, or ``None`` when it may be served; ``headers`` are
        looked up by lower-case name (Starlette's ``Headers``, or a lower-case ``dict``)."""
        host = headers.get("host")
        if not self._host_ok(host):
            return Refusal(
                421,
                "misdirected_request",
                f"this console does not answer to the host {host!r}: use its URL "
                f"(http://127.0.0.1:{self.port} or the one its stack printed)",
            )
        origin = headers.get("origin")
        if origin is not None:
            return Refusal(
                403,
                "cross_origin",
                f"refused: a request from a web page (Origin: {origin!r}); the console "
                "answers the rover commands only",
            )
        site = headers.get("sec-fetch-site")
        if site is not None and site.strip().lower() != "none":
            return Refusal(
                403,
                "cross_origin",
                f"refused: a browser's {site!r} request (Sec-Fetch-Site); the console "
                "answers the rover commands only",
            )
        given = bearer_token(headers.get("authorization"))
        if not token_matches(given, self.token):
            return Refusal(
                401,
                "unauthorized",
                "wrong token"
                if given
                else "this console needs its stack's token ('Authorization: Bearer "
                "<token>'; the rover commands take it from ROVER_CONSOLE_TOKEN or the "
                "stack's registry)",
            )
        if method == "POST":
            marked = headers.get(CONSOLE_HEADER.lower()) == "1"
            kind = (headers.get("content-type") or "").split(";", 1)[0].strip().lower()
            if not marked and kind != _JSON:
                return Refusal(
                    403,
                    "cross_origin",
                    f"refused: a POST here needs the header {CONSOLE_HEADER}: 1 (or "
                    f"Content-Type: {_JSON})",
                )
        return None

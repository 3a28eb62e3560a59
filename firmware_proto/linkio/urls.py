"""Link URLs: one parser for every tool that names a controller link.

- a **serial** link is a device path or a pyserial URL (``socket://HOST:PORT``,
  ``rfc2217://``, ``loop://``, ``spy://DEVICE``...). ``?baud=N`` (default 115200; a pty
  or a socket ignores it) is our own option, stripped before pyserial gets the rest
  verbatim (:func:`split_serial_url`).
- a **CAN** link is ``can://INTERFACE/CHANNEL[?node=N&OPTION=VALUE...]``; options other
  than ``node`` go to ``can.Bus``, numbers converted (:func:`parse_can_url`). Command
  lines write the bus as ``INTERFACE:CHANNEL`` (:func:`parse_can_spec`).

Pure but :func:`refuse_if_in_use`. A malformed URL raises
:class:`~firmware_proto.linkio.errors.LinkUrlError`, saying what is wrong and what is
expected.
"""

from __future__ import annotations

import errno
import fcntl
import os
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

from firmware_proto.linkio.errors import LinkBusyError, LinkUrlError

__all__ = [
    "DEFAULT_BAUD",
    "SERIAL_SCHEMES",
    "is_can_url",
    "parse_can_spec",
    "parse_can_url",
    "refuse_if_in_use",
    "split_serial_url",
]

DEFAULT_BAUD = 115200

_LOGGING = frozenset({"logging"})


@dataclass(frozen=True)
class _Scheme:
    """What a pyserial URL scheme needs.

    Attributes:
        options: the query options it takes (besides our ``baud``); ``None``: not
            checked here, pyserial checks them when the port opens.
        host_port: needs ``HOST:PORT``.
        target: wraps a device path (``spy://DEVICE``).
        exclusive: the port is a local device, opened exclusively.
    """

    options: frozenset[str] | None
    host_port: bool = False
    target: bool = False
    exclusive: bool = False


SERIAL_SCHEMES: dict[str, _Scheme] = {
    "": _Scheme(frozenset(), exclusive=True),  # a device path
    "socket": _Scheme(_LOGGING, host_port=True),
    "rfc2217": _Scheme(_LOGGING | {"ign_set_control", "poll_modem", "timeout"}, host_port=True),
    "loop": _Scheme(_LOGGING),
    "spy": _Scheme(frozenset({"file", "color", "raw", "all"}), target=True, exclusive=True),
    "alt": _Scheme(None),
    "hwgrep": _Scheme(None, exclusive=True),
    "cp2110": _Scheme(None),
}
"""The schemes pyserial's ``serial_for_url`` knows (``""``: a plain device path)."""


def split_serial_url(url: str, baud: int | None = None) -> tuple[str, int, bool]:
    """Check a serial URL (a device path or pyserial URL, with optional ``?baud=N``) and
    take our ``baud`` option out of it; ``baud`` given here overrides the URL's.

    Returns:
        (what to hand to pyserial, verbatim but for ``baud``; the baud rate in bit/s;
        whether to open it exclusively).
    """
    head, sep, query = url.partition("?")
    scheme = head.split("://", 1)[0].lower() if "://" in head else ""
    spec = SERIAL_SCHEMES.get(scheme)
    if spec is None:
        known = ", ".join(f"{s}://" for s in SERIAL_SCHEMES if s)
        raise LinkUrlError(f"{url!r}: unknown serial URL scheme {scheme!r}; known: {known}")
    kept: list[str] = []
    rate = DEFAULT_BAUD
    for item in query.split("&") if sep else []:
        key, _, value = item.partition("=")
        if key == "baud":
            try:
                rate = int(value)
            except ValueError:
                rate = 0
            if rate <= 0:
                raise LinkUrlError(f"{url!r}: baud must be a positive integer, got {value!r}")
        elif spec.options is not None and key not in spec.options:
            takes = ", ".join(sorted(spec.options | {"baud"}))
            where = f"{scheme}://" if scheme else "a device path"
            raise LinkUrlError(f"{url!r}: {where} takes no option {key!r}; it takes: {takes}")
        else:
            kept.append(item)
    rest = head[len(scheme) + 3 :] if scheme else head
    if spec.host_port:
        host, colon, port = rest.rstrip("/").rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise LinkUrlError(f"{url!r}: {scheme}:// needs HOST:PORT (port 1..65535)")
    if (spec.target or not scheme) and not rest:
        raise LinkUrlError(f"{url!r}: no device path")
    device = head + ("?" + "&".join(kept) if kept else "")
    return device, baud if baud is not None else rate, spec.exclusive


def refuse_if_in_use(url: str) -> None:
    """Fail with LinkBusyError when another process holds the device of ``url`` exclusively
    (pyserial's ``flock(LOCK_EX | LOCK_NB)``), e.g. a bridge already on it. An absent device,
    or a URL that is not a local device, passes: the link waits for those."""
    device, _, exclusive = split_serial_url(url)
    if not exclusive or "://" in device:
        return
    try:
        fd = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return  # not there (yet), or not permitted: the link reports and retries
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise LinkBusyError(
                f"{device} is held by another process (is a bridge already running on it?)"
            ) from exc
    finally:
        os.close(fd)  # also releases our lock


def parse_can_url(url: str) -> tuple[str, str, dict[str, Any]]:
    """``can://INTERFACE/CHANNEL?node=N&...`` -> (interface, channel, options)."""
    parts = urlsplit(url)
    interface, channel = parts.netloc, parts.path.lstrip("/")
    if parts.scheme != "can" or not interface or not channel:
        raise LinkUrlError(f"CAN URL must be can://INTERFACE/CHANNEL[?node=N], got {url!r}")
    options: dict[str, Any] = {}
    for key, values in parse_qs(parts.query).items():
        text = values[-1]
        options[key] = int(text, 0) if text.lstrip("-").isdigit() else text
    return interface, channel, options


def is_can_url(url: str) -> bool:
    """Whether ``url`` names a CAN link (``can://``) rather than a serial one."""
    return url.startswith("can://")


def parse_can_spec(text: str) -> tuple[str, str]:
    """``INTERFACE:CHANNEL`` (a command line's ``--can``) -> ``(interface, channel)``."""
    interface, sep, channel = text.partition(":")
    if not sep or not interface or not channel:
        raise LinkUrlError(
            f"expected INTERFACE:CHANNEL, e.g. socketcan:vcan0 or virtual:rover, got {text!r}"
        )
    return interface, channel
